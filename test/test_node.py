"""The node tensegrity_sim in a real rclpy context (own domain id): commands in over topics,
messages out, services, malformed commands, divergence, pacing logic and parameters."""
import dataclasses
import os

import numpy as np
import pytest
import yaml

rclpy = pytest.importorskip('rclpy')
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from std_msgs.msg import Float64MultiArray, MultiArrayDimension  # noqa: E402
from std_srvs.srv import SetBool, Trigger  # noqa: E402

from solver.build.scene import Scene  # noqa: E402
from solver.simulate.array import simulation_for  # noqa: E402
from tensegrity_ros.node.demo import Commander, spin_until  # noqa: E402
from tensegrity_ros.node.node import (DEFAULTS, ParameterError, TensegritySim,  # noqa: E402
                                      check_parameters)
from tensegrity_ros.node.pacing import (FAST_WORK_FRACTION, MIN_STEP_FRACTION, Pacer,  # noqa: E402
                                        MIN_WORK_FRACTION, WORK_FRACTION)
from tensegrity_ros.io.sinks import Sink  # noqa: E402

DOMAIN = 10 + os.getpid() % 20
N_PRISMS = 10
SMALL = ['structure.n_prisms=%d' % N_PRISMS]


class Ros:
    """One context, the node and a commander in one executor."""

    def __init__(self, tmp_path, sim=None, sets=(), **params):
        scene = Scene.load('config/scenes/fb_column.yaml').with_overrides(SMALL + list(sets))
        path = tmp_path / 'small.yaml'
        path.write_text(yaml.safe_dump(scene.data))
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, domain_id=DOMAIN)
        values = {'scene_file': str(path), 'real_time_factor': 0.0, **params}
        overrides = [Parameter(k, value=v) for k, v in values.items()]
        self.node = TensegritySim(sim=sim, context=self.ctx, parameter_overrides=overrides)
        self.sunk = []
        self.node.add_sink(Sink(
            message=lambda topic, msg, ns: self.sunk.append((topic, msg, ns))))
        self.cmd = Commander(context=self.ctx)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.ex.add_node(self.cmd)
        assert self.spin(self.cmd.connected, 30), 'commander never connected'

    def spin(self, predicate, timeout_s=20.0):
        return spin_until(self.ex, predicate, timeout_s, step_s=0.005)

    def call(self, client, request):
        assert client.wait_for_service(timeout_sec=10)
        future = client.call_async(request)
        assert self.spin(future.done, 10)
        return future.result()

    def close(self):
        self.ex.shutdown()
        self.node.close()
        self.cmd.destroy_node()
        self.node.destroy_node()
        rclpy.shutdown(context=self.ctx)


@pytest.fixture
def ros(tmp_path):
    r = Ros(tmp_path)
    yield r
    r.close()


def test_impact_in_strain_and_nodes_out(ros):
    net = ros.node.sim.network
    assert ros.spin(lambda: len(ros.cmd.strain) >= 3)
    assert np.abs(ros.cmd.strain[-1]).max() < 1e-12          # at rest before the impact
    n_s, n_c = len(ros.cmd.strain), len(ros.cmd.clouds)
    ros.cmd.impact([0.1])
    assert ros.spin(lambda: len(ros.cmd.strain) >= n_s + 40 and len(ros.cmd.clouds) >= n_c + 40)
    strains = np.array(ros.cmd.strain[n_s:])
    assert strains.shape[1:] == (1, N_PRISMS)
    assert strains.min() < -0.01                              # a compressive pulse
    assert np.all(np.isfinite(strains))
    t, x = ros.cmd.clouds[-1]
    assert x.shape == (net.n_nodes, 3)
    assert len(ros.cmd.tension[-1]) == net.n_cables
    times = np.array([c[0] for c in ros.cmd.clouds])
    assert np.all(np.diff(times) > 0)                         # stamps: simulation time, increasing
    steps = times / ros.node.sim.dt
    assert np.allclose(steps, np.round(steps), atol=1e-6)
    # the impacted (top) level moved down; the clamped level did not move
    top = [c[1][net.levels[0, -1], 2].mean() for c in ros.cmd.clouds[n_c:]]
    assert min(top) < net.x0[net.levels[0, -1], 2].mean() - 1e-4
    x0_f32 = net.x0.astype(np.float32).astype(np.float64)            # the cloud is float32
    assert np.allclose(x[net.levels[0, 0]], x0_f32[net.levels[0, 0]], rtol=0, atol=1e-9)
    assert ros.node.counts['accepted'] == 1 and ros.node.counts['rejected'] == 0
    # the command itself was handed to the recorder sinks
    assert any(topic.endswith('/cmd/impact') for topic, _, _ in ros.sunk)


def test_prestrain_changes_tensions_and_column_stays_at_rest(ros):
    net = ros.node.sim.network
    EA, p_new = net.meta['EA'], 0.004
    cross = np.array([k == 'cross' for k in net.cable_kind])
    ros.cmd.prestrain([p_new])
    assert ros.spin(lambda: ros.node.counts['accepted'] == 1)
    t_cmd = ros.node.sim.t                                    # the ramp starts on arrival
    assert ros.spin(lambda: ros.node.sim.t > t_cmd + ros.node.params['prestrain_ramp_s'] + 0.01)
    assert np.all(ros.node.sim.prestrain == p_new)
    n = len(ros.cmd.tension)
    assert ros.spin(lambda: len(ros.cmd.tension) > n + 2)
    T = ros.cmd.tension[-1]
    assert np.allclose(T[cross], EA * p_new, rtol=1e-9)      # T = EA (s - L) / L = EA p
    t, x = ros.cmd.clouds[-1]
    assert np.abs(x - net.x0).max() < 1e-7                   # float32 cloud of the reference
    assert np.abs(ros.node.sim.model.velocities()).max() < 1e-12
    assert np.abs(ros.cmd.strain[-1]).max() < 1e-9


def test_reset_service(ros):
    sim, net = ros.node.sim, ros.node.sim.network
    ros.cmd.impact([0.1])
    assert ros.spin(lambda: sim.t > 0.05)
    res = ros.call(ros.cmd.cli_running, SetBool.Request(data=False))
    assert res.success and not ros.node.running
    t_paused = sim.t
    ros.spin(lambda: False, 0.3)
    assert sim.t == t_paused and t_paused > 0.05
    n = len(ros.cmd.clouds)
    res = ros.call(ros.cmd.cli_reset, Trigger.Request())
    assert res.success
    # (reduced models rebuild positions by rotation: equal up to round-off)
    assert sim.t == 0.0 and np.allclose(sim.model.positions(), net.x0, rtol=0, atol=1e-15)
    assert np.abs(sim.model.velocities()).max() == 0.0
    assert ros.spin(lambda: len(ros.cmd.clouds) > n)
    t, x = ros.cmd.clouds[-1]
    # the clock runs on: the rest state comes one step after the last state, in episode 1
    assert ros.node.episode == 1 and 'episode 1' in res.message
    assert t == pytest.approx(t_paused + sim.dt, abs=1e-9)
    assert np.allclose(x, net.x0, rtol=1.2e-7, atol=1e-12)                    # float32
    times = [c[0] for c in ros.cmd.clouds]
    assert np.all(np.diff(times) > 0)
    ros.call(ros.cmd.cli_running, SetBool.Request(data=True))
    assert ros.spin(lambda: sim.t > 0.01)
    assert np.abs(sim.model.velocities()).max() < 1e-12     # at rest again: the impact is gone


def _malformed(rng, n_columns, n_cross):
    """One random malformed command: (topic, data, label)."""
    kind = rng.integers(8)
    topic = 'impact' if rng.random() < 0.5 else 'prestrain'
    good = 0.1 if topic == 'impact' else 0.003
    if kind == 0:
        return topic, [], ''                                       # empty
    if kind == 1:
        size = int(rng.choice([2, 3, 7, n_cross + 1, n_cross - 1]))
        return topic, [good] * size, ''                            # wrong length
    n = int(rng.choice([1, n_columns] if topic == 'impact' else [1, n_cross]))
    data = [good] * n
    i = int(rng.integers(n))
    if kind == 2:
        data[i] = float('nan')
    elif kind == 3:
        data[i] = float(rng.choice([np.inf, -np.inf]))
    elif kind == 4:                                                # outside the physical range
        data[i] = (float(rng.choice([-1, 1]) * rng.uniform(10.001, 1e6)) if topic == 'impact'
                   else float(rng.choice([rng.uniform(-1, 0), rng.uniform(0.5001, 10)])))
    elif kind == 5:
        return topic, data, str(rng.choice(['bogus', 'prism', 'xyz']))    # unknown label
    elif kind == 6:
        if topic == 'impact':                                      # label mismatch
            return topic, data, 'cross_cable'
        return topic, data, 'cross_cable' if n == 1 else 'all'
    else:
        if topic == 'prestrain':                                   # unequal within one prism
            data = [good] * n_cross
            data[3 * int(rng.integers(n_cross // 3)) + 1] = 0.004
        else:
            data[i] = float('nan') if rng.random() < 0.5 else 11.0
    return topic, data, ''


def test_malformed_commands_rejected_and_reported(ros):
    node, sim = ros.node, ros.node.sim
    ros.call(ros.cmd.cli_running, SetBool.Request(data=False))
    keep = [np.array(a) for a in (sim.model.positions(), sim.model.velocities(),
                                  sim.model.cable_rest_length, sim.prestrain)] + [sim.t]
    n_cross = len(sim.prestrain_map.cross)
    rng = np.random.default_rng(2024)
    n_diag = len([s for s in ros.sunk if s[0] == '/diagnostics'])
    sent = 0
    while sent < 1000:
        for _ in range(5):
            topic, data, label = _malformed(rng, sim.network.n_columns, n_cross)
            msg = Float64MultiArray()
            msg.data = [float(v) for v in data]
            if label:
                msg.layout.dim = [MultiArrayDimension(label=label, size=len(data),
                                                      stride=len(data))]
            (ros.cmd.pub_impact if topic == 'impact' else ros.cmd.pub_prestrain).publish(msg)
            sent += 1
        assert ros.spin(lambda: node.counts['rejected'] == sent, 10), \
            f'{node.counts} after {sent} commands ({node.intake.last_command})'
    assert node.counts == {'accepted': 0, 'rejected': 1000, 'superseded': 0,
                           'frames': node.counts['frames']}
    now = [sim.model.positions(), sim.model.velocities(), sim.model.cable_rest_length,
           sim.prestrain]
    assert all(np.array_equal(a, b) for a, b in zip(keep[:4], now)) and sim.t == keep[4]

    def reported():
        return [{kv.key: kv.value for kv in m.status[0].values} | {
            'level': m.status[0].level, 'message': m.status[0].message}
            for topic, m, _ in ros.sunk if topic == '/diagnostics'][n_diag:]
    # /diagnostics at their own rate (not one per command), with the counter and a warning
    assert ros.spin(lambda: any(d['commands_rejected'] == '1000' for d in reported()), 10)
    diags = reported()
    assert len(diags) < 100
    warned = [d for d in diags if d['message'].startswith('rejected')]
    assert warned and all(d['level'] == b'\x01' and '~/cmd/' in d['message'] for d in warned)
    # still alive: a good command after all that is accepted and the node steps on
    ros.call(ros.cmd.cli_running, SetBool.Request(data=True))
    ros.cmd.impact([0.05])
    assert ros.spin(lambda: node.counts['accepted'] == 1)
    assert ros.spin(lambda: sim.t > keep[4] + 0.01)


def _finite_outputs(sunk):
    for topic, msg, _ in sunk:
        if topic.endswith(('/strain', '/cable_tension')):
            assert np.all(np.isfinite(np.asarray(msg.data)))
        elif topic.endswith('/nodes'):
            assert np.all(np.isfinite(np.frombuffer(bytes(msg.data), dtype='<f4')))
        elif topic == '/diagnostics':
            assert all(kv.value.lower() not in ('nan', 'inf', '-inf')
                       for kv in msg.status[0].values)


def test_divergence_pauses_with_on_divergence_pause_and_publishes_no_nan(tmp_path):
    ros = Ros(tmp_path, on_divergence='pause')
    try:
        node, sim = ros.node, ros.node.sim
        ros.cmd.impact([0.1])
        assert ros.spin(lambda: sim.t > 0.02)
        sim.div = dataclasses.replace(sim.div, constraint_error=1e-300)  # every step diverges
        assert ros.spin(lambda: not node.running, 10)
        assert 'diverged' in node.problem and node.divergences == 1
        assert ros.spin(lambda: any(d[0] == 2 for d in ros.cmd.diagnostics), 5)
        t = sim.t
        ros.spin(lambda: False, 0.2)
        assert sim.t == t                                      # paused, last good state kept
        assert np.all(np.isfinite(sim.model.positions()))
        # a corrupted state (NaN) is never published either: the node pauses instead
        sim.div = dataclasses.replace(sim.div, constraint_error=1e-6)
        ros.call(ros.cmd.cli_running, SetBool.Request(data=True))
        sim.model.x[5, 0] = np.nan
        assert ros.spin(lambda: not node.running, 10)
        assert 'finite' in node.problem and node.divergences == 2
        _finite_outputs(ros.sunk)
    finally:
        ros.close()


def test_pacing_logic(ros):
    node, sim = ros.node, ros.node.sim
    pacer = node.pacer = Pacer(0.005, 1e-6)                   # measured nothing yet
    node.params['real_time_factor'] = 1.0
    pacer.anchor(sim.t, 100.0)
    assert node.steps_this_tick(100.01) == round(0.01 / sim.dt)
    node.params['real_time_factor'] = 2.5
    assert node.steps_this_tick(100.01) == round(0.025 / sim.dt)
    node.params['real_time_factor'] = 0.0                     # as fast as possible: no margin
    assert node.steps_this_tick(100.01) == int(FAST_WORK_FRACTION * 0.005 / 1e-6)
    # ... until the next tick is due: a tick that starts late (or spent time on commands) steps
    # less, so that the next one starts on time; one past its due time still steps a little
    left = 100.002 - 100.0
    assert node.steps_this_tick(100.0, deadline=100.002) == int(FAST_WORK_FRACTION * left / 1e-6)
    pacer.publish_cost = 0.0005
    assert node.steps_this_tick(100.0, deadline=100.002) == int(
        (FAST_WORK_FRACTION * left - 0.0005) / 1e-6)
    assert node.steps_this_tick(100.0, deadline=99.0) == int(MIN_WORK_FRACTION * 0.005 / 1e-6)
    pacer.publish_cost = 0.0
    # a solver too slow for the requested factor: the tick does what fits in 90 % of a period
    node.params['real_time_factor'] = 1.0
    pacer.step_cost = 1e-3
    assert node.steps_this_tick(101.0) == int(WORK_FRACTION * 0.005 / 1e-3) == 4
    assert pacer.anchor_wall == 101.0                          # no debt accumulated
    # a step that costs more than the budget (a column in lasting contact): the fraction of one
    # step that fits, never a whole one that overruns the tick
    pacer.step_cost = 0.02
    assert node.steps_this_tick(102.0) == pytest.approx(WORK_FRACTION * 0.005 / 0.02)
    assert pacer.anchor_t == pytest.approx(sim.t + WORK_FRACTION * 0.005 / 0.02 * sim.dt)
    node.params['real_time_factor'] = 0.0
    assert node.steps_this_tick(103.0, deadline=103.004) == pytest.approx(0.004 / 0.02)
    pacer.step_cost = 1e3                                      # never below the smallest fraction
    assert node.steps_this_tick(103.0, deadline=103.004) == MIN_STEP_FRACTION


def test_a_tick_takes_a_fraction_of_a_step_when_a_step_costs_more_than_a_period(ros):
    """The node's tick with a step that costs more than the publish period: it advances by
    the fraction of one step that fits (Simulation.advance_part), checked, and publishes that
    state; the frames keep coming, each at a later simulation time."""
    node, sim = ros.node, ros.node.sim
    ros.cmd.impact([0.1])
    assert ros.spin(lambda: node.intake.counts['accepted'] >= 1)
    node.pacer = Pacer(node.period, 1e3 * node.period)       # as if one step took 1,000 ticks
    node.pacer.stepped = lambda n, seconds: None              # keep that estimate
    n0, t0, step0 = len(ros.cmd.strain), sim.t, sim.step
    assert ros.spin(lambda: len(ros.cmd.strain) >= n0 + 20)
    assert sim.step - step0 >= 10                             # (a frame or two was in flight)
    assert 0.0 < sim.t - t0 < (sim.step - step0) * sim.dt * 0.01  # fractions of 1e-3 and less
    assert all(np.all(np.isfinite(s)) for s in ros.cmd.strain[n0:])
    assert abs(sim.energy_error()) < sim.div.energy_error


def test_parameters_file_matches_defaults_and_bad_values_named():
    with open('config/node.yaml') as f:
        raw = yaml.safe_load(f)
    (params,) = [v['ros__parameters'] for v in raw.values()]
    assert params == DEFAULTS
    for name, value in [('publish_rate_hz', 0.0), ('real_time_factor', -1.0),
                        ('marker_rate_hz', float('nan')), ('scene_file', 3), ('dt', -1e-3),
                        ('on_divergence', 'stop')]:
        with pytest.raises(ParameterError, match=name):
            check_parameters(dict(DEFAULTS, **{name: value}))
    assert check_parameters(dict(DEFAULTS, dt=0))['dt'] == 0.0


def test_chain1d_model_rejects_prestrain_and_takes_impacts(tmp_path):
    # paced: at real_time_factor 0 the cheap chain1d model runs some 80 simulated seconds per
    # wall second, and a slow reader could see the 10-prism column leave its force-law table
    # about 10 s after the impact (a pause) before it has its 20 frames
    r = Ros(tmp_path, model='chain1d', real_time_factor=1.0)
    try:
        assert r.node.sim.model.name == 'chain1d'
        r.cmd.prestrain([0.003])
        assert r.spin(lambda: r.node.counts['rejected'] == 1)
        assert 'chain1d' in r.node.intake.last_command[2]
        r.cmd.impact([0.1])
        assert r.spin(lambda: r.node.counts['accepted'] == 1)
        n = len(r.cmd.strain)
        assert r.spin(lambda: len(r.cmd.strain) > n + 20)
        assert min(s.min() for s in r.cmd.strain[n:]) < -0.01
    finally:
        r.close()


def test_commands_of_one_tick_are_validated_counted_and_the_last_one_applied(ros):
    """Three impacts and a malformed one before the next tick: the malformed one is rejected at
    once, the last valid impact is applied, the two before it are counted as superseded."""
    from tensegrity_ros.msgs import messages
    node = ros.node
    node.timer.cancel()               # no tick: nothing steps between the commands and the check
    try:
        for v in (0.01, 0.02, float('nan'), 0.03):
            node.intake.impact(messages.command_array([v], 'all'))
        assert node.counts['rejected'] == 1 and node.counts['accepted'] == 0
        node.intake.apply()           # what the next tick does first
    finally:
        node.timer.reset()
    assert node.counts['accepted'] == 1
    assert node.counts['superseded'] == 2 and node.counts['rejected'] == 1
    assert node.intake.last_command[2].startswith('impact v0 = [0.03] m/s')
    from solver.simulate.array import simulation_for
    fresh = simulation_for(node.sim.scene)                    # the same impact on a fresh column
    added = fresh.apply_impact(0.03)
    np.testing.assert_allclose(node.sim.model.velocities(), fresh.model.velocities(), atol=1e-12)
    assert f'+{added:.3g} J' in node.intake.last_command[2]


def test_a_flood_within_one_tick_is_counted_whole_the_last_valid_one_applied_logged_once(
        ros, monkeypatch):
    """500 commands (valid impacts and prestrains, malformed ones of both) before the next tick:
    each one is counted once (accepted + superseded + rejected == 500), the last valid one per
    topic is what the simulation gets, and the log has one line per kind (rejected, accepted)
    instead of one per command."""
    from tensegrity_ros.msgs import messages
    node, sim = ros.node, ros.node.sim
    node.timer.cancel()                                 # no tick until the check below
    node.params['prestrain_ramp_s'] = 0.0               # applied at once: checked at once
    lines = []

    class Log:                                          # what the node hands to rclpy's logger
        def __getattr__(self, level):
            return lambda text, **kw: lines.append((level, text))
    monkeypatch.setattr(node.log, 'logger', Log())
    node.log.last.clear()
    before = dict(node.counts)
    rng = np.random.default_rng(19)
    n, last, n_bad = 500, {}, 0
    for _ in range(n):
        u = rng.random()
        if u < 0.4:
            v = float(rng.uniform(-0.01, 0.01))
            assert node.intake.impact(messages.command_array([v], 'all'))
            last['~/cmd/impact'] = v
        elif u < 0.8:
            p = float(rng.uniform(0.001, 0.01))
            assert node.intake.prestrain(messages.command_array([p], 'all'))
            last['~/cmd/prestrain'] = p
        else:
            bad = [[float('nan')], [float('inf')], [11.0], [0.1, 0.1]][rng.integers(4)]
            handler = node.intake.impact if rng.random() < 0.5 else node.intake.prestrain
            assert not handler(messages.command_array(bad, 'all'))
            n_bad += 1
    order = list(node.intake.pending)                         # applied in this order at the tick
    assert sorted(order) == sorted(last)
    node.intake.apply()                                       # what the next tick does first
    node.timer.reset()
    assert node.counts['accepted'] == before['accepted'] + 2
    d = {k: node.counts[k] - before[k] for k in ('accepted', 'superseded', 'rejected')}
    assert d['rejected'] == n_bad and sum(d.values()) == n
    fresh = simulation_for(sim.scene)                       # the last ones on a fresh column
    for key in order:
        if key == '~/cmd/impact':
            fresh.apply_impact(last[key])
        else:
            fresh.apply_prestrain(last[key])
    np.testing.assert_array_equal(sim.prestrain, fresh.prestrain)
    np.testing.assert_allclose(sim.model.velocities(), fresh.model.velocities(), atol=1e-12)
    assert [lv for lv, _ in lines].count('warning') == 1            # one 'rejected ...' line
    assert [lv for lv, _ in lines].count('info') == 1               # one accepted one
    assert lines[0][1].startswith('rejected ~/cmd/')


def test_commands_are_taken_by_the_tick_or_a_reset_never_by_the_executor(ros):
    """The command subscriptions are not the executor's (TakenByTick): with the timer stopped a
    command waits in its subscription, validated by nobody; a reset takes what waits (applied,
    then the reset), and ticks take the rest."""
    node, sim = ros.node, ros.node.sim
    before = dict(node.counts)
    node.timer.cancel()
    try:
        ros.cmd.impact([float('nan')])
        ros.cmd.impact([0.1])
        ros.spin(lambda: False, 0.5)                    # delivered, not taken
        assert node.counts == before
        response = ros.call(ros.cmd.cli_reset, Trigger.Request())
        assert response.success
        assert node.counts['rejected'] == before['rejected'] + 1
        assert node.counts['accepted'] == before['accepted'] + 1   # applied before the reset
        assert sim.t == 0.0 and not np.any(sim.model.velocities())
        ros.cmd.prestrain([0.004])
        ros.spin(lambda: False, 0.3)
        assert node.counts['accepted'] == before['accepted'] + 1
    finally:
        node.timer.reset()
    assert ros.spin(lambda: node.counts['accepted'] == before['accepted'] + 2)
