"""A prestrain ramp gives, bit for bit, the run of its obvious twin: one-column simulations whose
prestrain is set at once (``apply_prestrain(..., ramp_s=0)``) to the ramp's interpolated value
before every single step, each stepping once, and to the value at the frame's end after the
frame's last step; once a column's ramp has ended, the rest of its frame in one call. Checked for
an array of distinct columns (every way it steps: one column at a time, lanes, ``auto``) through
ramps longer than a frame, a ramp started mid-ramp and a ramp of some columns, and for every
integrator, steps shortened by ``advance_part`` included. The energy balance error (whose scale
the twin's extra steps see more often) is compared with the Python path of the ramp
(``Loading._ramp_record`` None, one integrator call a step), which also equals the twin."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from solver.build.scene import Scene
from solver.simulate.array import ArraySimulation
from solver.simulate.loading import Loading
from solver.simulate.simulation import Simulation

ROOT = Path(__file__).resolve().parents[1]

FB = 'config/scenes/fb_column.yaml'
FRAME = 4                       # steps a frame


class Twin:
    """One column stepped the obvious way: ``spec`` the running ramp ``(t0, duration, start,
    target)`` or None, ``t`` the clock of the simulation it stands beside (frames of whole
    steps)."""

    def __init__(self, sim):
        self.sim, self.spec, self.t = sim, None, 0.0

    def command(self, target, ramp_s):
        self.spec = (self.t, ramp_s, self.sim.prestrain[0].copy(), np.array(target, float))

    def _set(self, k, dt):
        t0, duration, start, target = self.spec
        u = (self.t + k * dt - t0) / duration
        if u >= 1.0:
            p, self.spec = target, None
        else:
            p = start + max(u, 0.0) * (target - start)
        self.sim.apply_prestrain(p[None, :], ramp_s=0.0)

    def frame(self, n):
        dt = self.sim.dt
        for k in range(n):
            if self.spec is None:
                self.sim.advance((n - k) * dt)
                break
            self._set(k, dt)
            self.sim.advance(dt)
        if self.spec is not None:
            self._set(n, dt)
        self.t += n * dt

    def part(self, fraction):
        """One step shortened to ``fraction`` of ``dt`` (``advance_part``)."""
        dt = fraction * self.sim.dt
        if self.spec is not None:
            self._set(0, dt)
        self.sim.advance_part(fraction)
        if self.spec is not None:
            self._set(1, dt)
        self.t += 1 * dt


def same(sim, twin, what):
    """The state, prestrain, rest lengths and work of ``sim`` (a one-column simulation) equal the
    twin's, bit for bit; returns its energy balance error."""
    a, b = sim, twin.sim
    assert np.array_equal(a.model.positions(), b.model.positions()), what
    assert np.array_equal(a.model.velocities(), b.model.velocities()), what
    assert np.array_equal(a.prestrain, b.prestrain), what
    assert np.array_equal(a.model.cable_rest_length, b.model.cable_rest_length), what
    assert a.energy_work() == b.energy_work(), what
    assert a.t == twin.t, what
    return a.energy_error()


def both_paths(run, monkeypatch, compiled_calls=True):
    """``run()`` (the energy balance errors it saw) with the ramp compiled and in Python: the
    same, bit for bit. ``compiled_calls``: whether the first run stepped in ramped calls."""
    calls = []
    went = Loading._ramp_went           # after every ramped call, a lane group's too
    with monkeypatch.context() as mp:
        mp.setattr(Loading, '_ramp_went', lambda self, *args: calls.append(
            went(self, *args)) or calls[-1])
        compiled = run()
    assert any(c is not None for c in calls) == compiled_calls
    with monkeypatch.context() as mp:
        mp.setattr(Loading, '_ramp_record', lambda self: None)
        python = run()
    assert compiled == python


@pytest.mark.parametrize('lanes', [False, True, 'auto'])
def test_array_ramps_equal_their_twin(lanes, monkeypatch):
    both_paths(lambda: _array_run(lanes), monkeypatch)


def _array_run(lanes):
    nc = 4
    sim = ArraySimulation(Scene.load(FB).with_overrides([('structure.n_columns', nc),
                                                         ('structure.n_prisms', 12)]))
    sim.lanes, sim.threads = lanes, 1
    twins = [Twin(Simulation(sim.column_scene)) for _ in range(nc)]
    dt, n_p = sim.dt, sim.network.n_prisms
    p0 = np.linspace(0.02, 0.05, nc)
    sim.apply_prestrain(p0, ramp_s=0.0)
    sim.apply_impact(0.1)
    for c, tw in enumerate(twins):
        tw.sim.apply_prestrain(p0[c], ramp_s=0.0)
        tw.sim.apply_impact(0.1)

    errors = []

    def frames(count, what):
        for i in range(count):
            sim.advance(FRAME * dt)
            for tw in twins:
                tw.frame(FRAME)
            for g in sim.groups:
                for c in g.columns:
                    errors.append(same(g.sim, twins[c], f'{what}, frame {i}, column {c}'))

    frames(2, 'plain')
    target = np.outer(p0[::-1], np.linspace(1.0, 1.5, n_p))    # per prism, per column
    sim.apply_prestrain(target, ramp_s=11.5 * dt)              # about three frames
    for c, tw in enumerate(twins):
        tw.command(target[c], 11.5 * dt)
    frames(2, 'ramp')
    sub = [1, 2]                                # mid-ramp, two of the columns, a shorter ramp
    sim.apply_prestrain([0.03, 0.06], columns=sub, ramp_s=6 * dt)
    for c in sub:
        twins[c].command(np.full(n_p, [0.03, 0.06][sub.index(c)]), 6 * dt)
    frames(4, 'mid-ramp')
    assert sim.prestrain_goal.tolist() == sim.prestrain.tolist()      # every ramp ended
    frames(1, 'after')
    return errors


@pytest.mark.parametrize('method', ['rk4_projected', 'rk4', 'rattle', 'dopri54_projected',
                                    'implicit_midpoint'])
def test_single_simulation_ramps_equal_their_twin(method, monkeypatch):
    both_paths(lambda: _single_run(method), monkeypatch, method != 'implicit_midpoint')


def _single_run(method):
    sets = [('structure.n_prisms', 10), ('integrator.method', method),
            ('divergence.energy_error', 1.0)]
    if method == 'implicit_midpoint':
        sets.append(('contact.bars', 'none'))
    scene = Scene.load(FB).with_overrides(sets)
    sim, twin = Simulation(scene), Twin(Simulation(scene))
    for s in (sim, twin.sim):
        s.apply_impact(0.1)
    dt, n_p = sim.dt, sim.network.n_prisms
    errors = []
    for i, (p, ramp_s) in enumerate([(np.full(n_p, 0.004), 5.5 * dt),
                                     (np.linspace(0.003, 0.006, n_p), 7 * dt)]):
        sim.apply_prestrain(p[None, :], ramp_s=ramp_s)
        twin.command(p, ramp_s)
        for f in range(4):
            sim.advance(FRAME * dt)
            twin.frame(FRAME)
            errors.append(same(sim, twin, f'{method}, ramp {i}, frame {f}'))
    sim.apply_prestrain(0.005, ramp_s=2 * dt)                 # steps shortened to part of dt
    twin.command(np.full(n_p, 0.005), 2 * dt)
    for f, fraction in enumerate([0.5, 0.75, 1.0, 0.5, 0.5]):
        sim.advance_part(fraction)
        twin.part(fraction)
        errors.append(same(sim, twin, f'{method}, parts, {f}'))
    return errors


@pytest.mark.parametrize('columns, lanes', [(1, 'off'), (3, 'off'), (3, 'on')])
def test_the_node_loads_the_ramped_step_at_start_and_leaves_the_state_as_loaded(
        columns, lanes, monkeypatch):
    """``warm_commands`` (the node's start, after timing a step): the ramped twin runs (an array
    that steps as lanes: its ramped lane call, then its plain lane call), and the simulation is
    the freshly loaded one again: positions, velocities, time, prestrain, balance, and the steps
    it then takes equal those of a simulation never warmed."""
    from solver.simulate.array import simulation_for
    from solver.simulate.lanebatch import LaneGroup
    from tensegrity_ros.node.params import warm_commands
    scene = Scene.load(ROOT / 'config' / 'scenes' / 'fb_column.yaml').with_overrides(
        [('structure.n_columns', columns), ('integrator.lanes', lanes)])
    warmed, fresh = simulation_for(scene), simulation_for(scene)
    calls = []
    real = LaneGroup._advance_ramped if lanes == 'on' else Loading._ramped

    def counted(self, *args):
        calls.append(real(self, *args))
        return calls[-1]
    plain = []
    real_step = LaneGroup._step

    def stepped(self, *args):
        plain.append(len(self.sims))
        return real_step(self, *args)
    with monkeypatch.context() as mp:
        mp.setattr(LaneGroup if lanes == 'on' else Loading,
                   '_advance_ramped' if lanes == 'on' else '_ramped', counted)
        mp.setattr(LaneGroup, '_step', stepped)
        warm_commands(warmed)
    assert any(out is not None for out in calls)        # stepped by the compiled twin
    assert bool(plain) == (lanes == 'on')               # and the plain lane steps after it
    for sim in (warmed, fresh):
        sim.apply_impact(0.1)
        sim.advance(0.05)
    assert warmed.t == fresh.t and warmed.step == fresh.step
    assert np.array_equal(warmed.frame().positions, fresh.frame().positions)
    assert np.array_equal(warmed.prestrain, fresh.prestrain)
    assert warmed.energy_error() == fresh.energy_error()
