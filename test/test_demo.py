"""The demo (node in a second process, commander over DDS, own domain id) against the headless run
of the same scene: the same pulse figures, the impact at the node's start."""
import os

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from solver.analysis import observables  # noqa: E402

from solver.simulate import runner
from solver.build.scene import Scene  # noqa: E402
from solver.simulate.array import simulation_for
from tensegrity_ros.node.demo import (demo_domain_id, run_demo,  # noqa: E402
                                      stamped_strain)

SCENE = 'config/scenes/fb_column.yaml'


@pytest.fixture(scope='module')
def headless():
    scene, sim = runner.prepare(SCENE)          # what `tensegrity run` does: impact v0 = 0.1
    assert scene['loading.impact.v0'] == 0.1
    clouds = []                # what ~/nodes carries: float32 points
    rec = runner.run(sim, 1.2, scene.data['run']['output_dt'],
                     on_frame=lambda f: clouds.append(f.positions.astype(np.float32)))
    rec.clouds = clouds
    return rec, sim.network


def test_demo_matches_the_headless_run(tmp_path, headless):
    s = run_demo(SCENE, v0=[0.1], duration_s=1.35, rtf=1.0, out_dir=tmp_path, record=False,
                 domain_id=230 + os.getpid() % 2)
    assert s['node_exit_code'] == 0, s['node_output_tail']
    assert s['t_impact'] < 0.1                      # the clock waited for the commander
    assert s['strain_frames'] > 100 and s['sim_span_s'] >= 1.3   # past the end arrival (1.195 s)
    rec, net = headless
    ref = rec.pulses[0]
    got = s['pulses'][0]
    assert ref.speed_m_s == pytest.approx(0.255, rel=0.01)   # the paper's column at 0.1 m/s
    assert got['speed_m_s'] == pytest.approx(ref.speed_m_s, rel=0.01)
    assert got['arrival_end_s'] == pytest.approx(ref.arrival_end_s, abs=0.01)
    # the tolerance tells the float32 points' figures from the float64 ones
    s32 = np.array([observables.prism_strains(x.astype(np.float64), net.levels, net.h0)
                    for x in rec.clouds])
    speed32 = observables.first_passage(rec.times, s32[:, 0], net.h0).speed_m_s
    assert not speed32 == pytest.approx(ref.speed_m_s, rel=0.01)
    assert s['min_strain'] == pytest.approx(rec.strain.min(), rel=0.02)


def test_strain_stamps_come_from_the_matching_cloud():
    """Each float64 strain message gets the stamp of the cloud of the same frame; one whose cloud
    was dropped is left out; the float32 cloud's own strain differs by its rounding."""
    from solver.build.structures import build_network
    net = build_network(Scene.load(SCENE))
    sim = simulation_for(Scene.load(SCENE))
    sim.apply_impact(0.1)
    clouds, strains = [], []
    for _ in range(6):
        sim.advance(40 * sim.dt)
        f = sim.frame()
        clouds.append((f.t, f.positions.astype(np.float32).astype(np.float64)))
        strains.append(np.array(f.strain, dtype=np.float64))
    dropped = clouds[:2] + clouds[3:]
    t, s = stamped_strain(dropped, strains, net.levels, net.h0)
    assert list(t) == [c[0] for c in dropped]
    assert np.array_equal(s, np.array(strains[:2] + strains[3:]))
    s32 = observables.prism_strains(clouds[0][1], net.levels, net.h0)
    assert 0 < np.abs(s32 - strains[0]).max() < 1e-4


def test_demo_domain_ids_stay_in_their_range():
    ids = {demo_domain_id(pid) for pid in range(1000, 1100)}
    assert min(ids) == 100 and max(ids) == 149 and len(ids) == 50


def test_demo_focus_prints_the_plan_measured_arrivals_and_gain(tmp_path, monkeypatch, capsys):
    """``tensegrity demo --focus``: the node plans the design's prestrains, its own run meets
    the delay law within 1 ms, the table and the focal gain are printed, the node's Rerun
    recording holds the field images (finite) and its MCAP log the ~/field messages."""
    import json

    import yaml
    from rerun.chunk import RrdReader

    from mcap.reader import make_reader
    from solver.studies import lens
    from tensegrity_ros.cli import main
    monkeypatch.setenv('TENSEGRITY_CACHE', str(tmp_path / 'cache'))
    small = Scene.load('config/scenes/lens_focus.yaml').with_overrides(
        ['structure.n_prisms=10', 'structure.n_columns=3', 'lens.grid=9', 'run.t_end=0.3'])
    path = tmp_path / 'small_lens.yaml'
    path.write_text(yaml.safe_dump(small.data))
    out = tmp_path / 'out'
    code = main(['demo', '--focus', '0.02,0.1', '--medium-speed', '2', '--scene', str(path),
                 '--rtf', '0', '--out', str(out), '--domain-id', str(230 + os.getpid() % 2)])
    text = capsys.readouterr().out
    assert code == 0, text
    s = json.loads((out / 'summary.json').read_text())
    plan = lens.design(small, (0.02, 0.1), 2.0, 0.1)
    assert [c['prestrain'] for c in s['columns']] == pytest.approx(
        [c['prestrain'] for c in plan.columns], rel=1e-9)
    xs = np.arange(3) * small['structure.column_spacing']
    law = s['t0_s'] - np.hypot(xs - 0.02, 0.1) / 2.0              # T_i = T0 - |F - X_i| / C
    sim = np.array([c['simulated_s'] for c in s['columns']])
    assert np.max(np.abs(sim - law)) <= 1e-3
    for c in s['columns']:
        assert f"{c['prestrain']:11.5f} " in text and f"{1e3 * c['residual_s']:13.3f}" in text
    assert s['focal_gain'] == pytest.approx(s['p_focus'] / s['p_focus_uniform'])
    assert f"focal gain {s['focal_gain']:.3f}" in text
    assert s['field_shape'] == [48, 64] and np.isfinite(s['field_max'])
    images = []
    for chunk in RrdReader(s['outputs']['rerun']).stream():
        if chunk.entity_path == '/field/peak_pressure':
            rb = chunk.to_record_batch()
            for row in rb.column('Image:buffer').to_pylist():
                images.append(np.array(row[0], dtype=np.uint8).view(np.float32))
    assert images and all(np.isfinite(v).all() and v.size == 48 * 64 for v in images)
    assert images[-1].max() == pytest.approx(1.0)            # over the scale of the last map
    from tensegrity_ros.io.mcap_reader import McapLog
    with open(McapLog(s['outputs']['mcap']).path, 'rb') as f:        # the bag folder's file
        fields = [m for _, channel, m in make_reader(f).iter_messages()
                  if channel.topic.endswith('/field')]
    assert len(fields) >= 1


def test_demo_compiles_the_kernels_first_and_a_failed_compile_is_one_line(tmp_path, monkeypatch,
                                                                          capsys):
    """``tensegrity demo`` compiles the kernels (on every core, announced) before it starts the
    node; when that fails it says so in one line, exits 2 and starts nothing."""
    from solver.simulate import precompile
    from tensegrity_ros.cli import main
    from tensegrity_ros.node import demo
    calls = []

    def failing(*args, **kw):
        calls.append('compile')
        raise RuntimeError('precompile failed for rk4: no result after 1 s')

    monkeypatch.setattr(precompile, 'compile_all', failing)
    monkeypatch.setattr(demo, 'run_demo', lambda *a, **kw: calls.append('node'))
    code = main(['demo', '--out', str(tmp_path / 'out')])
    err = capsys.readouterr().err
    assert code == 2 and calls == ['compile']
    assert err.strip().count('\n') == 0 and 'precompile failed for rk4' in err
