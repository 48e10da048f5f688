"""Batched runs (:mod:`solver.simulate.batch`): every figure of a batched point equals the single
run of the same point (:func:`solver.simulate.runner.simulate`), for a batch that mixes impacts (a
train among them), prestrains and geometries; a point that diverges in a batch is reported
``diverged`` with the single run's reason while the other rows are unchanged."""
import math
from pathlib import Path

import numpy as np
import pytest

from solver.simulate.batch import BatchSimulation, simulate_batch
from solver.simulate.runner import simulate
from solver.simulate.simulation import SimulationDiverged

ROOT = Path(__file__).resolve().parents[1]
FB = str(ROOT / 'config' / 'scenes' / 'fb_column.yaml')
SHORT = ['structure.n_prisms=20', 'run.t_end=0.3']
TIMING = ('wall_time_s', 'real_time_factor')
POINTS = [
    SHORT,
    SHORT + ['loading.impact.v0=0.06', 'prestrain=0.0035'],
    SHORT + ['loading.impact.period=0.02', 'loading.impact.count=4'],          # a train
    SHORT + ['structure.radius=0.006', 'prestrain=0.0015'],
    SHORT + ['structure.h0=0.007', 'loading.impact.v0=0.13'],
    SHORT + ['materials.cable_damping_ratio=0.002', 'contact.lock=penalty'],
]
# a step too long for the bar contact at 1 m/s: the energy ledger stops the run
DIVERGING = SHORT + ['contact.resolution=4', 'loading.impact.v0=1.0']


def _same(a, b, path=''):
    """Every figure of ``a`` equals ``b``'s to 1e-9 relative (timings left out); returns the
    paths that differ."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and set(a) == set(b), path
        return [d for k in a if k not in TIMING for d in _same(a[k], b[k], f'{path}.{k}')]
    if isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), path
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in _same(x, y, f'{path}[{i}]')]
    if isinstance(a, float) and isinstance(b, float):
        return [] if math.isclose(a, b, rel_tol=1e-9, abs_tol=0.0) else [(path, a, b)]
    return [] if a == b else [(path, a, b)]


@pytest.fixture(scope='module')
def singles():
    return [simulate(FB, p).summary.to_json() for p in POINTS]


@pytest.mark.parametrize('threads, together', [(1, False), (2, False), (2, True)])
def test_every_figure_of_a_batched_point_is_that_of_its_single_run(singles, threads, together):
    got = simulate_batch([(FB, p) for p in POINTS], threads=threads, together=together)
    assert [g.status for g in got] == ['ok'] * len(POINTS)
    for p, single, g in zip(POINTS, singles, got):
        assert _same(single, g.summary.to_json()) == [], p
    # the points differ: the comparison is not of one run with itself
    figures = [(s['energy_work_J'], s['pulse']['speed_m_s'], s['base']) for s in singles]
    assert sum(f[1] is not None for f in figures) >= 4
    assert len({repr(f) for f in figures}) == len(figures)
    assert len(got[2].summary.to_json()['impacts']) == 4


def test_full_frames_give_the_same_figures_as_the_lean_record(singles):
    frames = []
    got = simulate_batch([(FB, POINTS[2])], threads=1,
                         on_frame=lambda k, f: frames.append(f))
    assert _same(singles[2], got[0].summary.to_json()) == []
    assert len(frames) == len(got[0].point.record.times)
    assert frames[-1].positions.shape == (got[0].point.sim.network.n_nodes, 3)


@pytest.mark.parametrize('together', [False, True])
def test_a_diverging_point_stops_alone_and_the_others_rows_are_unchanged(singles, together):
    with pytest.raises(SimulationDiverged) as info:
        simulate(FB, DIVERGING)
    items = [(FB, POINTS[0]), (FB, DIVERGING), (FB, POINTS[2]),
             (FB, SHORT + ['prestrain=0.9'])]                   # out of range: an error
    finished = []
    got = simulate_batch(items, threads=2, together=together,
                         on_point=lambda k, bp: finished.append(k))
    assert sorted(finished) == [0, 1, 2, 3]
    assert [g.status for g in got] == ['ok', 'diverged', 'ok', 'error']
    assert got[1].reason == str(info.value).splitlines()[0]
    assert 'energy balance' in got[1].reason and got[1].summary is None
    assert 'prestrain' in got[3].reason
    assert _same(singles[0], got[0].summary.to_json()) == []
    assert _same(singles[2], got[2].summary.to_json()) == []


def test_a_batch_steps_its_instances_and_stops_only_the_one_that_diverges():
    from solver.build.scene import Scene
    scenes = [Scene.load(FB).with_overrides(o) for o in (SHORT, DIVERGING)]
    with BatchSimulation.of(scenes, threads=2) as batch:
        for sim in batch.sims:
            sim.apply_impact(1.0 if sim is batch[1] else 0.1)
        twin = Scene.load(FB).with_overrides(SHORT)
        from solver.simulate.array import simulation_for
        alone = simulation_for(twin)
        alone.apply_impact(0.1)
        for _ in range(60):
            batch.advance(0.005)
            alone.advance(0.005)
        assert batch.status == ['running', 'diverged']
        assert batch[0].t == pytest.approx(0.3) and batch[0].t == alone.t and batch[1].t < 0.3
        np.testing.assert_array_equal(batch[0].model.x, alone.model.x)
        np.testing.assert_array_equal(batch[0].model.v, alone.model.v)


def test_without_the_base_force_every_other_figure_is_the_single_runs(singles):
    got = simulate_batch([(FB, p) for p in POINTS[:3]], threads=2, base=False)
    for single, g in zip(singles, got):
        assert g.summary.to_json()['base'] == [] != single['base']
        assert _same({k: v for k, v in single.items() if k != 'base'},
                     {k: v for k, v in g.summary.to_json().items() if k != 'base'}) == []


def test_an_array_scene_runs_in_a_batch_as_it_runs_alone():
    """An array of columns (its own ArraySimulation) in a batch of lean records."""
    point = (str(ROOT / 'config' / 'scenes' / 'lens_array.yaml'),
             ['structure.n_prisms=10', 'run.t_end=0.1'])
    single = simulate(*point).summary.to_json()
    got = simulate_batch([point], threads=1, base=False)[0]
    assert got.status == 'ok', got.reason
    assert _same({k: v for k, v in single.items() if k != 'base'},
                 {k: v for k, v in got.summary.to_json().items() if k != 'base'}) == []


def test_a_point_that_diverges_at_its_first_step_gives_one_reason_alone_and_in_a_batch():
    """Its load makes the first step fail (gravity 1e4 m/s^2): the single run reports its own
    first step, impact applied, as the batch does, not a step taken before the run."""
    point = SHORT + ['loading.gravity=1e4']
    with pytest.raises(SimulationDiverged) as info:
        simulate(FB, point)
    got = simulate_batch([(FB, point), (FB, SHORT)], threads=1)
    assert [g.status for g in got] == ['diverged', 'ok']
    assert got[0].reason == str(info.value).splitlines()[0]
    assert 'step 1' in got[0].reason and 'energy balance' in got[0].reason
