"""tensegrity sweep and fit in this process: diverged points as rows, resuming, an interrupted
sweep, batches (their sizes, a topology per batch, the batched path resuming), point ids that
change with the solver source, Latin hypercube points, figures that move smoothly with a
parameter, the fitted scene's description, bad input. The sweep on Dask, its rows against
`tensegrity run --json` and the fit on the cluster: test_sweep_cluster.py."""
from pathlib import Path

import numpy as np
import pytest

from tensegrity_ros import cli
from tensegrity_ros.studies import batching, grid
from tensegrity_ros.studies import sweep as sw

from sweep_helpers import FB, RB, T_END
from sweep_helpers import figures as _figures


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


@pytest.mark.parametrize('threads', [1, 2])
def test_an_interrupted_sweep_keeps_its_finished_rows(tmp_path, threads):
    """One thread: one batch of the four points, stopped at its first row. Two threads: a
    batch of two each; the other thread's batch finishes and keeps both its rows (the rows of
    finished batches, never part of one)."""
    sweep = sw.build(FB, ['loading.impact.v0=0.06,0.08,0.1,0.12'], out=tmp_path, t_end=0.05)
    seen = []

    def interrupt(row):
        seen.append(row['point_id'])
        if len(seen) == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        sw.execute(sweep, on_row=interrupt, threads=threads)
    kept = sw.read_rows(tmp_path)
    assert sorted(kept) == sorted(seen)
    assert len(kept) == 1 if threads == 1 else len(kept) in (1, 3)
    assert all(r['status'] == 'ok' for r in kept.values())
    import pyarrow.parquet as pq
    assert pq.read_table(tmp_path / sw.TABLE).num_rows == len(kept)
    assert sw.execute(sweep)[1] == 4 - len(kept)


@pytest.mark.parametrize('n, workers', [(1, 2), (7, 2), (64, 2), (1000, 2), (500, 7)])
def test_batches_cover_every_point_once_in_order_and_shrink_to_single_points(n, workers):
    batches = sw.chunks(range(n), workers)
    assert [i for b in batches for i in b] == list(range(n))
    sizes = [len(b) for b in batches]
    assert all(1 <= k <= batching.MAX_BATCH for k in sizes)
    assert sizes == sorted(sizes, reverse=True)
    # the points left after a batch keep at least GUIDED_SHARE batches of that size per worker
    for i, k in enumerate(sizes):
        left = sum(sizes[i:])
        assert k == 1 or k * batching.GUIDED_SHARE * workers <= left
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
                              ('prestrain', float(p)), ('run.t_end', T_END)]
                         ).summary.to_json()['pulse']
        for n in names:
            figs[n].append(pulse[n])
    assert f'{figs["amplitude"][0]:.4f}' != f'{figs["amplitude"][-1]:.4f}'
    for n in names:
        d = np.diff(figs[n])
        assert np.all(d != 0), n
        assert np.all(np.sign(d) == np.sign(d[0])), n
        ratio = d[1:] / d[:-1]
        assert np.all((ratio > 0.6) & (ratio < 1.6)), (n, ratio)


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


def test_contact_cost_grows_with_the_fastest_shot_of_a_train():
    from solver.build.scene import Scene
    base = Scene.load(FB)
    plain = sw.point_cost(base)
    slow = base.with_overrides([('loading.impact.v0', 0.05)])
    fast = base.with_overrides([('loading.impact.v0', -0.2)])         # its speed counts
    train = base.with_overrides([('loading.impact.v0', 0.05),
                                 ('loading.impact.times', [0.0, 0.1]),
                                 ('loading.impact.velocities', [0.05, 0.2])])
    assert sw.contact_cost(slow) == pytest.approx(plain * (1 + 0.05 / batching.CONTACT_SPEED))
    assert sw.contact_cost(fast) == pytest.approx(plain * (1 + 0.2 / batching.CONTACT_SPEED))
    assert sw.contact_cost(train) == pytest.approx(sw.contact_cost(fast))


def test_in_process_batches_go_to_the_threads_dearest_first(tmp_path, monkeypatch):
    """The threads take the batches in the order given: the fastest shots first (longest
    processing time first), every point once, the rows those of the points."""
    import solver
    given = []

    def in_order(fn, items, n):
        items = list(items)
        given.extend(sorted({o['loading.impact.v0'] for _, o in b}) for b in items)
        return [(True, fn(b)) for b in items]
    monkeypatch.setattr(solver, 'on_threads', in_order)
    sweep = sw.build(FB, ['loading.impact.v0=0.02,0.2,0.08', 'prestrain=0.002,0.003'],
                     out=tmp_path, t_end=0.01)
    rows, n = sw.execute(sweep, threads=3)
    assert given == [[0.2], [0.08], [0.02]]             # grid order would be 0.02, 0.2, 0.08
    assert n == 6 and all(r['status'] == 'ok' for r in rows)
    assert sorted((r['loading.impact.v0'], r['prestrain']) for r in rows) == sorted(
        (v, p) for v in (0.02, 0.2, 0.08) for p in (0.002, 0.003))
    assert sw.dearest_first([['a'], ['b'], ['c']], [1.0, 1.0, 2.0]) == [['c'], ['a'], ['b']]
