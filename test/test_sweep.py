"""tensegrity sweep and fit: rows against `tensegrity run --json`, the Dask cluster against the
serial run, diverged points, resuming, a killed worker, a fit that recovers known values, smooth
figures, bad input."""
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from tensegrity_ros import cli
from tensegrity_ros.studies import grid, table
from tensegrity_ros.studies import sweep as sw

ROOT = Path(__file__).resolve().parents[1]
FB = str(ROOT / 'config' / 'scenes' / 'fb_column.yaml')
RB = str(ROOT / 'config' / 'scenes' / 'rb_column.yaml')
T_END = 0.55                      # past t_ref = 0.5 s: every figure is defined
GRID = ['loading.impact.v0=0.08,0.12', 'structure.stacking=shared,parallel']
TIMING = table.TIMING_FIELDS


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


def _figures(row):
    return {k: v for k, v in row.items() if k not in TIMING}


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


def test_a_diverged_point_is_a_row(tmp_path, capsys):
    # the rigid-base column of line bars at 1 m/s: its bars cross at once (tensegrity run exits 1)
    assert cli.main(['run', RB, '--v0', '1', '--t-end', '0.05', '--set', 'contact.bars=none']) == 1
    sweep = sw.build(RB, ['loading.impact.v0=0.1,1', 'contact.bars=none'], out=tmp_path,
                     t_end=0.05)
    rows, _ = sw.execute(sweep)
    assert [r['status'] for r in rows] == ['ok', 'diverged']
    assert 'diverged' in rows[1]['reason'] and '\n' not in rows[1]['reason']
    assert rows[1]['pulse.amplitude'] is None
    assert cli.main(['sweep', RB, '--grid', 'loading.impact.v0=0.1,1', '--grid',
                     'contact.bars=none', '--t-end', '0.05',
                     '--out', str(tmp_path / 'cli'), '--workers', '1',
                     '--plot', 'pulse.amplitude']) == 0
    assert (tmp_path / 'cli' / 'pulse.amplitude.png').stat().st_size > 0


def test_a_resumed_sweep_runs_only_the_missing_points(tmp_path):
    ran = []

    def task(scene, overrides, pid):
        ran.append(dict(overrides))
        return sw.run_point(scene, overrides, pid)

    first = sw.build(FB, ['loading.impact.v0=0.08,0.1'], out=tmp_path, t_end=0.05)
    sw.execute(first, task=task)
    assert len(ran) == 2
    ran.clear()
    # same points again in another spelling and order, plus one new
    again = sw.build(FB, ['loading.impact.v0=0.12,0.1,0.08'], out=tmp_path, t_end=0.05)
    rows, n = sw.execute(again, task=task)
    assert n == 1 and ran == [{'loading.impact.v0': 0.12, 'run.t_end': 0.05}]
    assert [r['loading.impact.v0'] for r in rows] == [0.12, 0.1, 0.08]
    assert sw.execute(again, task=task)[1] == 0


def test_an_interrupted_sweep_keeps_its_finished_rows(tmp_path):
    sweep = sw.build(FB, ['loading.impact.v0=0.08,0.1,0.12'], out=tmp_path, t_end=0.05)

    def interrupt(row):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        sw.execute(sweep, on_row=interrupt)
    assert len(sw.read_rows(tmp_path)) == 1
    import pyarrow.parquet as pq
    assert pq.read_table(tmp_path / sw.TABLE).num_rows == 1
    assert sw.execute(sweep)[1] == 2


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
    sweep = sw.build(FB, grid, out=tmp_path / 'cluster', t_end=1.0)
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
    local, _ = sw.execute(sw.build(FB, grid, out=tmp_path / 'local', t_end=1.0))
    for a, b in zip(rows, local):
        assert {k: v for k, v in a.items() if k not in TIMING} == \
            {k: v for k, v in b.items() if k not in TIMING}


@pytest.mark.parametrize('n, workers', [(1, 2), (7, 2), (64, 2), (1000, 2), (500, 7)])
def test_batches_cover_every_point_once_in_order_and_shrink_to_single_points(n, workers):
    batches = sw.chunks(range(n), workers)
    assert [i for b in batches for i in b] == list(range(n))
    sizes = [len(b) for b in batches]
    assert all(1 <= k <= sw.MAX_BATCH for k in sizes)
    assert sizes == sorted(sizes, reverse=True)
    # the points left after a batch keep at least GUIDED_SHARE batches of that size per worker
    for i, k in enumerate(sizes):
        left = sum(sizes[i:])
        assert k == 1 or k * sw.GUIDED_SHARE * workers <= left
    assert sizes[-min(n, workers):] == [1] * min(n, workers)   # the last tasks are single points
    assert [len(b) for b in sw.chunks(range(10), 2, size=4)] == [4, 4, 2]


def test_a_point_gets_a_new_id_when_the_solver_source_changes(tmp_path):
    import shutil
    import solver
    src = tmp_path / 'solver'
    shutil.copytree(Path(solver.__file__).parent, src,
                    ignore=shutil.ignore_patterns('__pycache__'))
    before = grid.source_hash(src)
    assert before == grid.code_version()                  # the same files, the same hash
    path = src / 'kernels' / 'dynamics.py'        # a kernel edit in a sub-package
    path.write_text(path.read_text() + '\n# changed\n')
    after = grid.source_hash(src)
    assert after != before
    data, point = {'a': 1}, {'prestrain': 0.003}
    assert sw.point_id(data, point, code=before) == sw.point_id(data, point, code=before)
    assert sw.point_id(data, point, code=before) != sw.point_id(data, point, code=after)


def test_latin_hypercube_points_are_seeded_and_stratified():
    axes = [sw.parse_axis('prestrain=0.002:0.004'), sw.parse_axis('structure.radius=0.004:0.005'),
            sw.parse_axis('structure.stacking=shared,parallel')]
    a = sw.points(axes, samples=8, seed=3)
    assert a == sw.points(axes, samples=8, seed=3) != sw.points(axes, samples=8, seed=4)
    assert len(a) == 16
    p = np.array([pt['prestrain'] for pt in a[:8]])
    # one sample in each eighth of the range
    assert sorted(np.floor((p - 0.002) / 0.00025).astype(int)) == list(range(8))


def test_small_parameter_changes_move_the_figures_continuously():
    """Over a fine prestrain grid (radius 4.2 mm, parallel base cables, v0 = 0.1) the figures
    change at every step, monotonically, with first differences that vary slowly (a figure read
    at the nearest prism and frame moves in steps: equal values, or jumps)."""
    from solver.simulate.runner import simulate
    ps = np.linspace(0.0030, 0.0035, 6)
    names = ('amplitude', 'amplitude_median', 'amplitude_max', 'speed_m_s',
             'speed_snapshot_m_s')
    figs = {n: [] for n in names}
    for p in ps:
        pulse = simulate(FB, [('structure.radius', 0.0042), ('structure.stacking', 'parallel'),
                              ('prestrain', float(p)), ('run.t_end', T_END)]).summary['pulse']
        for n in names:
            figs[n].append(pulse[n])
    assert f'{figs["amplitude"][0]:.4f}' != f'{figs["amplitude"][-1]:.4f}'
    for n in names:
        d = np.diff(figs[n])
        assert np.all(d != 0), n
        assert np.all(np.sign(d) == np.sign(d[0])), n
        ratio = d[1:] / d[:-1]
        assert np.all((ratio > 0.6) & (ratio < 1.6)), (n, ratio)


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
    assert result['runs'] == 2 * result['evaluations']
    out = tmp_path / 'best.yaml'
    fit.write_scene(problem, best, out)
    from solver.build.scene import Scene
    assert Scene.load(out)['structure.radius'] == best['structure.radius']


def test_written_scene_describes_the_fitted_values_not_the_old_ones(tmp_path):
    """fb_column's description says "cross prestrain 0.002": the fitted scene's names the values
    found instead, and loads with them."""
    from solver.build.scene import Scene
    from tensegrity_ros.studies import fit
    target = tmp_path / 'target.yaml'
    target.write_text('cases: [{figures: {pulse.amplitude: 0.05}}]\n')
    problem = fit.build(FB, target, ['prestrain=0.0025:0.0035'],
                        ['structure.stacking=shared,parallel'])
    best = {'prestrain': 0.0031234567, 'structure.stacking': 'parallel'}
    out = tmp_path / 'best.yaml'
    fit.write_scene(problem, best, out, target=str(target))
    scene = Scene.load(out)
    assert scene['prestrain'] == best['prestrain']
    assert scene['structure.stacking'] == 'parallel'
    text = scene['description']
    assert '0.002' not in text, text
    assert 'prestrain = 0.00312346' in text and 'structure.stacking = parallel' in text
    assert str(target) in text


@pytest.mark.parametrize('args, needle', [
    (['sweep', FB, '--grid', 'structure.nope=1,2'], 'structure.nope: unknown key'),
    (['sweep', FB, '--grid', 'prestrain=0.004:0.002:3'], 'must be greater than START'),
    (['sweep', FB, '--grid', 'prestrain=0.001:0.9:3'], 'prestrain: 0.9 is outside'),
    (['sweep', FB, '--grid', 'structure.stacking=shared,diagonal'], "'diagonal' is not one of"),
    (['sweep', FB, '--grid', 'prestrain=0.002:0.003'], 'needs a count'),
    (['sweep', FB, '--grid', 'prestrain=1,2', '--plot', 'pulse.nope'], 'unknown figure'),
    (['sweep', FB, '--grid', 'prestrain=0.002', '--dashboard-address', '8787'],
     '--dashboard-address 8787: expected HOST:PORT'),
    (['sweep', FB, '--grid', 'prestrain=0.002', '--no-dashboard', '--scheduler', 'tcp://[::1]:1'],
     'a --scheduler has its own'),
    (['fit', FB, '--target', 'TARGET', '--free', 'prestrain=0.002:0.003'], None),
])
def test_bad_input_is_one_line_exit_2_and_runs_nothing(args, needle, tmp_path, capsys):
    if 'TARGET' in args:
        bad = tmp_path / 't.yaml'
        cases = [
            ('cases: [{figures: {pulse.amp: 0.05}}]', "unknown figure 'pulse.amp'"),
            ('cases: [{figures: {pulse.amplitude: 0.05}, weights: {pulse.speed_m_s: 1}}]',
             'not among its figures'),
            ('cases: {a: 1}', 'non-empty list'),
            ('cases: [{set: {loading.nope: 1}, figures: {pulse.amplitude: 0.05}}]',
             'loading.nope: unknown key'),
            ('cases: [: bad', 'not valid YAML'),
        ]
        for text, msg in cases:
            bad.write_text(text)
            capsys.readouterr()
            assert cli.main([a if a != 'TARGET' else str(bad) for a in args]) == 2
            err = capsys.readouterr().err
            assert msg in err and err.count('\n') == 1, (text, err)
        for extra, msg in ((['--free', 'structure.radius=0.005:0.004'], 'greater than START'),
                           (['--choice', 'structure.bases=flexible,soft'], "'soft' is not one")):
            bad.write_text('cases: [{figures: {pulse.amplitude: 0.05}}]')
            assert cli.main(['fit', FB, '--target', str(bad), *extra]) == 2
            err = capsys.readouterr().err
            assert msg in err and err.count('\n') == 1, err
        return
    out = tmp_path / 'out'
    capsys.readouterr()
    assert cli.main([*args, '--out', str(out), '--workers', '1']) == 2
    err = capsys.readouterr().err
    assert needle in err and err.count('\n') == 1 and 'Traceback' not in err
    assert not out.exists()


def test_a_batched_sweep_resumes_and_reports_every_point(tmp_path):
    """The default (batched) path: one progress tick and one row per point, a rerun runs only
    the missing points, the rows equal those of single runs (``task=run_point``)."""
    ticks = []
    first = sw.build(FB, ['loading.impact.v0=0.08,0.1'], out=tmp_path / 'b', t_end=0.05)
    rows, n = sw.execute(first, progress=ticks.append, threads=2)
    assert n == 2 and ticks == [1, 1]
    single = sw.build(FB, ['loading.impact.v0=0.12,0.1,0.08'], out=tmp_path / 's', t_end=0.05)
    ref, _ = sw.execute(single, task=sw.run_point)
    ticks.clear()
    plain = sw.build(FB, ['loading.impact.v0=0.12,0.1,0.08'], out=tmp_path / 'b', t_end=0.05)
    rows, n = sw.execute(plain, progress=ticks.append)
    assert n == 1 and ticks == [1]
    assert [_figures(r) for r in rows] == [_figures(r) for r in ref]


def test_batches_keep_a_topology_together_and_cover_every_point_once():
    topo = [sw.topology_of(o) for o in ({'structure.stacking': 'shared', 'prestrain': 0.002},
                                        {'structure.stacking': 'parallel', 'prestrain': 0.002},
                                        {'structure.stacking': 'shared', 'prestrain': 0.003},
                                        {'structure.radius': 0.004}, {'structure.radius': 0.005})]
    assert topo[0] == topo[2] != topo[1] and topo[3] == topo[4] == ()
    n = 40
    topos = [topo[i % 2] for i in range(n)]
    got = sw.batches(list(range(n)), 2, [0.1] * n, topos)
    assert sorted(i for b in got for i in b) == list(range(n))
    assert all(len({topos[i] for i in b}) == 1 for b in got)
    assert max(len(b) for b in got) * 0.1 <= sw.BATCH_SECONDS + 1e-9
    assert [len(b) for b in got][-1] == 1                       # guided: shrinks to one point
    alone = sw.batches(list(range(n)), None, [0.1] * n, [()] * n, seconds=1.0)
    assert [len(b) for b in alone] == [10] * 4
