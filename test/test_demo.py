"""The demo (node in a second process, commander over DDS, own domain id) against the headless run
of the same scene: the same pulse figures, the impact at the node's start."""
import os

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from solver import observables, runner  # noqa: E402
from solver.scene import Scene  # noqa: E402
from solver.simulation import Simulation  # noqa: E402
from tensegrity_ros.commander import (demo_domain_id, run_demo,  # noqa: E402
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
    from solver.simulation import build_network
    net = build_network(Scene.load(SCENE))
    sim = Simulation(Scene.load(SCENE))
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
