"""tensegrity sweep and fit on Dask: the rows of a serial sweep against `tensegrity run --json`
and as the reference of the rows of a LocalCluster and of a `dask scheduler` with `dask worker`
processes; the sockets a sweep's cluster listens on (loopback unless asked); a worker killed
during a sweep and while it runs a batch, losing no row; a fit on the cluster that recovers known
values. The sweep in this process: test_sweep.py."""
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from tensegrity_ros import cli
from tensegrity_ros.studies import table
from tensegrity_ros.studies import sweep as sw

from sweep_helpers import FB, ROOT, T_END, TIMING
from sweep_helpers import figures as _figures

GRID = ['loading.impact.v0=0.08,0.12', 'structure.stacking=shared,parallel']


@pytest.fixture(scope='module')
def cluster():
    c = sw.Cluster(workers=2)
    yield c
    c.close()


@pytest.fixture(scope='module')
def serial_rows(tmp_path_factory):
    sweep = sw.build(FB, GRID, out=tmp_path_factory.mktemp('serial'), t_end=T_END)
    rows, n = sw.execute(sweep)
    assert n == 4
    return rows


def _run_json(capsys, *args):
    capsys.readouterr()
    assert cli.main(['run', *args, '--json']) == 0
    return json.loads(capsys.readouterr().out)


def test_a_sweep_row_equals_the_run_summary_of_the_same_point(serial_rows, capsys):
    row = serial_rows[3]
    assert (row['loading.impact.v0'], row['structure.stacking']) == (0.12, 'parallel')
    summary = _run_json(capsys, FB, '--set', 'loading.impact.v0=0.12',
                        '--set', 'structure.stacking=parallel', '--t-end', str(T_END))
    assert row['status'] == 'ok'
    for key, value in summary['pulse'].items():
        assert row[f'pulse.{key}'] == value, key             # exactly
    for key in ('energy_drift_rel', 'constraint_error_rel', 'steps', 'steps_taken', 'dt'):
        assert row[key] == summary[key], key
    # every figure defined by t_end (the pulse has not reached the clamped end yet)
    assert all(math.isfinite(row[f'pulse.{k}']) for k in table.PULSE_FIELDS
               if k not in ('speed_arrival_m_s', 'arrival_end_s'))


@pytest.mark.parametrize('chunk', [None, 3])
def test_the_cluster_sweep_returns_the_rows_of_the_serial_sweep(cluster, serial_rows, tmp_path,
                                                               chunk):
    sweep = sw.build(FB, GRID, out=tmp_path, t_end=T_END)
    rows, n = sw.execute(sweep, cluster, chunk=chunk)          # 3: a task of 3 points, one of 1
    assert n == 4
    assert [_figures(r) for r in rows] == [_figures(r) for r in serial_rows]
    assert len({r['worker_pid'] for r in rows} - {os.getpid()}) >= 1     # ran on the workers
    # the table on disk holds the same rows
    import pyarrow.parquet as pq
    table = pq.read_table(tmp_path / sw.TABLE).to_pylist()
    assert [r['pulse.amplitude'] for r in table] == [r['pulse.amplitude'] for r in rows]
    assert (tmp_path / sw.CSV).read_text().count('\n') == 5


LOOPBACK = ('127.0.0.1', '::1')


def _listening():
    """(ip, port) of the TCP sockets listening in this process and its child processes."""
    import psutil
    procs = [psutil.Process()]
    procs += procs[0].children(recursive=True)
    found = set()
    for proc in procs:
        try:
            found |= {(c.laddr.ip, c.laddr.port) for c in proc.net_connections(kind='tcp')
                      if c.status == psutil.CONN_LISTEN}
        except psutil.NoSuchProcess:
            pass
    return found


@pytest.mark.parametrize('option, dashboard_ip', [
    ([], '127.0.0.1'), (['--dashboard-address', '0.0.0.0:0'], '0.0.0.0'),
    (['--no-dashboard'], None)])
def test_a_sweep_listens_on_loopback_only_unless_asked(option, dashboard_ip, tmp_path, capsys,
                                                       monkeypatch):
    """The sockets the sweep's LocalCluster opens (scheduler, nannies, workers, dashboard), seen
    once it is up: all on loopback; the dashboard, whose link the command prints, on every
    interface only with --dashboard-address 0.0.0.0:PORT."""
    before = _listening()
    seen = {}

    def spy(sweep, cluster=None, **kwargs):        # the cluster is up: its sockets, no run
        seen['sockets'] = _listening() - before
        seen['workers'] = cluster.n_workers
        return [], 0

    monkeypatch.setattr(sw, 'execute', spy)
    capsys.readouterr()
    assert cli.main(['sweep', FB, '--grid', 'loading.impact.v0=0.1', '--t-end', '0.01',
                     '--workers', '2', '--out', str(tmp_path), *option]) == 0
    err = capsys.readouterr().err
    assert seen['workers'] == 2
    sockets = seen['sockets']
    links = [line for line in err.splitlines() if line.startswith('dashboard: ')]
    if dashboard_ip is None:
        assert links == []
        public = set()
    else:
        assert len(links) == 1, err
        port = int(links[0].split('http://127.0.0.1:')[1].split('/')[0])
        public = {(ip, p) for ip, p in sockets if p == port}
        assert {ip for ip, _ in public} == {dashboard_ip}, sockets
    # the scheduler, and a nanny and a worker per worker process, at least
    assert len(sockets - public) >= 5, sockets
    assert all(ip in LOOPBACK for ip, _ in sockets - public), sockets
    assert all(ip in LOOPBACK for ip, _ in sockets) == (dashboard_ip != '0.0.0.0')


def _stop(procs):
    """Terminate ``procs`` (Popen: a scheduler, then its workers) and the processes they started;
    kill what is left. The workers go first: without their scheduler they wait for it to come
    back before they exit."""
    import psutil
    family = []
    for proc in procs:
        try:
            family += psutil.Process(proc.pid).children(recursive=True)
        except psutil.NoSuchProcess:
            pass
    for group in (procs[1:], procs[:1]):
        for proc in group:
            proc.terminate()
        for proc in group:
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
    for child in family:                  # a worker process its nanny left behind
        try:
            if child.status() != psutil.STATUS_ZOMBIE:
                child.kill()
        except psutil.NoSuchProcess:
            pass


def test_a_sweep_on_a_dask_scheduler_and_workers_returns_the_rows_of_the_serial_sweep(
        serial_rows, tmp_path, capsys):
    """The cluster users start on their machines: ``dask scheduler`` and two ``dask worker``
    processes (here on loopback, the project on their PYTHONPATH), a sweep with --scheduler."""
    import psutil
    from distributed import Client
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(ROOT), *[p for p in os.environ.get('PYTHONPATH', '').split(os.pathsep) if p]]))
    file = tmp_path / 'scheduler.json'
    dask = [sys.executable, '-m', 'dask']            # the `dask` command of this environment
    log = (tmp_path / 'dask.log').open('w')
    procs = []
    try:
        procs.append(subprocess.Popen(
            [*dask, 'scheduler', '--host', '127.0.0.1', '--port', '0', '--no-dashboard',
             '--scheduler-file', str(file)], env=env, cwd=tmp_path, stdout=log, stderr=log))
        for _ in range(2):
            procs.append(subprocess.Popen(
                [*dask, 'worker', '--scheduler-file', str(file), '--host', '127.0.0.1',
                 '--nthreads', '1', '--no-dashboard'], env=env, cwd=tmp_path, stdout=log,
                stderr=log))
        for _ in range(600):
            if file.exists() or any(p.poll() is not None for p in procs):
                break
            time.sleep(0.05)
        assert all(p.poll() is None for p in procs), (tmp_path / 'dask.log').read_text()
        with Client(scheduler_file=str(file), timeout='30s') as client:
            client.wait_for_workers(2, timeout=60)
            address = client.scheduler.address
            # the workers run this checkout (not another install of the package)
            where = client.run(lambda: __import__('tensegrity_ros').__file__)
            assert {str(Path(f).parents[1]) for f in where.values()} == {str(ROOT)}, where
        pids = {p.pid for p in procs[1:]}
        pids |= {c.pid for p in procs[1:] for c in psutil.Process(p.pid).children(recursive=True)}
        out = tmp_path / 'out'
        assert cli.main(['sweep', FB, *[a for g in GRID for a in ('--grid', g)],
                         '--t-end', str(T_END), '--scheduler', address, '--out', str(out)]) == 0
        assert 'dashboard' not in capsys.readouterr().err
        rows = sw.read_rows(out)
        assert [_figures(rows[r['point_id']]) for r in serial_rows] == \
            [_figures(r) for r in serial_rows]
        assert {r['worker_pid'] for r in rows.values()} <= pids        # ran on the workers
    finally:
        _stop(procs)
        log.close()


def _die_once(scene, overrides, pid, marker):
    """Kills its own worker process the first time it runs (a marker file remembers)."""
    marker = Path(marker)
    if not marker.exists():
        marker.write_text(str(os.getpid()))
        os._exit(1)
    return sw.run_point(scene, overrides, pid)


def test_a_worker_killed_during_a_sweep_loses_no_row(cluster, tmp_path):
    import cloudpickle
    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    import functools
    marker = tmp_path / 'killed'
    sweep = sw.build(FB, ['loading.impact.v0=0.08,0.1,0.12'], out=tmp_path / 'out', t_end=0.05)
    try:
        rows, n = sw.execute(sweep, cluster, task=functools.partial(_die_once, marker=str(marker)))
    finally:
        cloudpickle.unregister_pickle_by_value(sys.modules[__name__])
    assert marker.exists()                             # a worker did die
    assert n == 3 and [r['status'] for r in rows] == ['ok'] * 3
    assert int(marker.read_text()) not in {r['worker_pid'] for r in rows}


def test_a_worker_killed_while_it_runs_a_batch_loses_no_row(cluster, tmp_path):
    """The batched path (one task per batch, no custom task): a worker process is killed while a
    batch runs on it; its nanny starts a new one, the scheduler runs the batch again, and every
    row is that of the same sweep run in this process."""
    import signal
    import threading
    grid = ['loading.impact.v0=0.08,0.1,0.12,0.14']
    sweep = sw.build(FB, grid, out=tmp_path / 'cluster', t_end=3.0)  # killed mid-batch
    result = {}
    runner = threading.Thread(target=lambda: result.update(
        out=sw.execute(sweep, cluster, chunk=2)))
    runner.start()
    client = cluster.client
    victim = None
    deadline = time.monotonic() + 120
    while victim is None and time.monotonic() < deadline:
        busy = [w for w, keys in client.processing().items() if keys]
        if busy:
            victim = client.run(os.getpid, workers=[busy[0]])[busy[0]]
        time.sleep(0.05)
    assert victim is not None, 'no worker ever ran a batch'
    os.kill(victim, signal.SIGKILL)                    # its batch is queued or under way
    runner.join(300)
    assert not runner.is_alive()
    rows, n = result['out']
    assert n == 4 and [r['status'] for r in rows] == ['ok'] * 4, [r['reason'] for r in rows]
    assert victim not in {r['worker_pid'] for r in rows}
    local, _ = sw.execute(sw.build(FB, grid, out=tmp_path / 'local', t_end=3.0))
    for a, b in zip(rows, local):
        assert {k: v for k, v in a.items() if k not in TIMING} == \
            {k: v for k, v in b.items() if k not in TIMING}


def _target(tmp_path):
    """Figures of the project's own runs at radius 4.2 mm, prestrain 0.003, parallel base cables
    (not the defaults) at two impact velocities."""
    from solver.simulate.runner import simulate
    cases = []
    for v0 in (0.02, 0.1):
        s = simulate(FB, [('structure.radius', 0.0042), ('prestrain', 0.003),
                          ('structure.stacking', 'parallel'), ('loading.impact.v0', v0),
                          ('run.t_end', T_END)]).summary
        f = sw.flatten(s)
        cases.append({'set': {'loading.impact.v0': v0},
                      'figures': {k: f[k] for k in ('pulse.amplitude', 'pulse.amplitude_median',
                                                    'pulse.speed_m_s')}})
    path = tmp_path / 'target.yaml'
    path.write_text(yaml.safe_dump({'cases': cases}))
    return path


def test_fit_recovers_known_values_with_a_continuous_and_a_discrete_key(cluster, tmp_path):
    from tensegrity_ros.studies import fit
    problem = fit.build(FB, _target(tmp_path), ['structure.radius=0.0038:0.0046',
                                                'prestrain=0.0025:0.0035'],
                        ['structure.stacking=shared,parallel'], t_end=T_END)
    result = fit.fit(problem, cluster, seed=1, popsize=2, maxiter=2)
    best = result['best']
    assert best['structure.stacking'] == 'parallel'
    assert best['structure.radius'] == pytest.approx(0.0042, rel=0.02)
    assert best['prestrain'] == pytest.approx(0.003, rel=0.02)
    assert [c['choice']['structure.stacking'] for c in result['combinations']] == \
        ['parallel', 'shared']
    # two cases per point, and per free key two runs of each case for its range
    assert result['runs'] == 2 * (result['evaluations'] + 2 * len(result['free']))
    out = tmp_path / 'best.yaml'
    fit.write_scene(problem, best, out)
    from solver.build.scene import Scene
    assert Scene.load(out)['structure.radius'] == best['structure.radius']
