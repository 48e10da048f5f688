"""The Dask cluster of sweeps and fits: an existing scheduler (``--scheduler``) or a
``LocalCluster`` on this machine whose scheduler, workers and dashboard listen on 127.0.0.1 unless
``--dashboard-address`` says otherwise."""
from __future__ import annotations

import os
import sys
import time

from tensegrity_ros.studies.grid import SweepError

DASHBOARD = '127.0.0.1:0'        # the local cluster's dashboard: this machine only, a free port
WILDCARD_HOSTS = ('0.0.0.0', '::', '[::]')


def parse_dashboard(value):
    """``HOST:PORT`` of ``--dashboard-address`` checked (the host resolves, the port is 0-65535;
    0 = a free port), returned as given; raises :class:`SweepError` with a one-line message."""
    import socket
    host, sep, port = str(value).rpartition(':')
    if not sep or not host or not port.isdigit() or int(port) > 65535:
        raise SweepError(f'--dashboard-address {value}: expected HOST:PORT, e.g. 127.0.0.1:8787 '
                         'or 0.0.0.0:8787 (every interface)')
    try:
        socket.getaddrinfo(host.strip('[]'), None)
    except (OSError, UnicodeError) as exc:
        raise SweepError(f'--dashboard-address {value}: unknown host {host} ({exc})') from None
    return value


class Cluster:
    """A Dask client: on ``address`` (an existing scheduler) or on a ``LocalCluster`` of
    ``workers`` single-threaded worker processes started here and shut down by :meth:`close`.
    The local scheduler and workers listen on 127.0.0.1 only, and so does its dashboard unless
    ``dashboard`` (``HOST:PORT``) says otherwise; ``dashboard=None`` starts none."""

    def __init__(self, workers=None, address=None, dashboard=DASHBOARD):
        from distributed import Client, LocalCluster
        self.cluster = None
        self.timings = {}
        self.dashboard_host = None
        t0 = time.perf_counter()
        if address:
            try:
                self.client = Client(address, timeout='20s')
            except (OSError, TimeoutError, ValueError) as exc:
                raise SweepError(f'--scheduler {address}: cannot connect ({exc})') from None
        else:
            n = workers or os.cpu_count() or 1
            self.cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                        host='127.0.0.1', dashboard_address=dashboard,
                                        silence_logs=40)
            self.client = Client(self.cluster)
            self.dashboard_host = dashboard and dashboard.rpartition(':')[0]
        self.timings['cluster_start_s'] = time.perf_counter() - t0

    @property
    def dashboard_link(self):
        """The local cluster's dashboard, ``http://HOST:PORT/status`` (HOST 127.0.0.1 when it
        listens on every interface, then said in brackets after it), or None: no local cluster,
        or no dashboard."""
        if self.cluster is None or not self.dashboard_host:
            return None
        port = self.cluster.scheduler_info.get('services', {}).get('dashboard')
        if port is None:
            return None
        host = self.dashboard_host
        if host in WILDCARD_HOSTS:
            return f'http://127.0.0.1:{port}/status (listening on every interface, {host})'
        return f'http://{host}:{port}/status'

    def report_dashboard(self, file=None):
        """One line on stderr with :attr:`dashboard_link`, if there is one."""
        if self.dashboard_link:
            print(f'dashboard: {self.dashboard_link}', file=file or sys.stderr, flush=True)

    @property
    def n_workers(self):
        return len(self.client.scheduler_info(n_workers=-1)['workers'])

    def map(self, func, items, **kwargs):
        """``[func(item) for item in items]`` on the cluster (the map-like callable of
        :func:`scipy.optimize.differential_evolution`)."""
        futures = self.client.map(func, list(items), pure=False, **kwargs)
        return self.client.gather(futures)

    def close(self):
        try:
            self.client.close()
        finally:
            if self.cluster is not None:
                self.cluster.close()


def dashboard_option(args):
    """The ``dashboard`` of :class:`Cluster` from ``--dashboard-address`` and ``--no-dashboard``
    (checked; raises :class:`SweepError`): :data:`DASHBOARD` by default, None for no dashboard.
    Both options are about the local cluster; with ``--scheduler`` they are an error."""
    address = getattr(args, 'dashboard_address', None)
    off = getattr(args, 'no_dashboard', False)
    if (address or off) and args.scheduler:
        raise SweepError(f'{"--no-dashboard" if off else "--dashboard-address"}: sets the '
                         'dashboard of the local cluster; a --scheduler has its own')
    if address and off:
        raise SweepError('--dashboard-address and --no-dashboard: give one or the other')
    return None if off else parse_dashboard(address) if address else DASHBOARD
