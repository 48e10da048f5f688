"""bench.shots --census on 50 ms of each shot: its classes of intervals cover every interval of
``dt`` and every step once, and its counts agree with the run's own (the steps the simulation
took, the contacts the scans met: a struck column's bars touch within 50 ms at 1 and 2 m/s)."""
import json

import pytest

from bench import shots


@pytest.fixture(scope='module')
def rows(tmp_path_factory):
    out = tmp_path_factory.mktemp('census')
    path, = shots.census(out, log=lambda *a: None, t_end=0.05)
    return json.loads(open(path).read())['rows']


def test_every_interval_and_step_is_counted_once(rows):
    assert [(r['scene'], r['v0']) for r in rows] == list(shots.CASES)
    for r in rows:
        dt = shots._scene(r['scene']).integrator.dt
        assert sum(r['intervals'].values()) == round(0.05 / dt)
        assert sum(r['interval_steps'].values()) == r['steps']
        assert sum(r['steps_by_contact_level'].values()) == r['steps']
        assert r['interval_steps']['one step'] == r['intervals']['one step']


def test_the_counts_are_the_runs_own(rows):
    """The steps equal a run of the same shot stepped one dt at a time; a contact is met at
    every speed, and the intervals that met one take more than one step each."""
    for r in rows:
        scene, sim = shots._at_rest(shots._scene(r['scene']), [f"loading.impact.v0={r['v0']!r}"])
        sim.apply_impact(r['v0'])
        for _ in range(sum(r['intervals'].values())):
            sim.advance(sim.dt)
        assert sim.steps_taken == r['steps']
        met = r['intervals']['contact met']
        assert met > 0 and r['interval_steps']['contact met'] > met
        assert r['touching_pairs_max'] >= 1
