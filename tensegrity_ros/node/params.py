"""Parameters of the node ``tensegrity_sim``: defaults (mirrored by ``config/node.yaml``), checks,
and the :class:`~solver.simulate.simulation.Simulation` they describe. No ROS imports: usable by
tests and tools without a ROS context."""
from __future__ import annotations

import math
import time

import numpy as np

from solver import Scene
from solver import SimulationDiverged
from solver import simulation_for

# Defaults of every parameter (config/node.yaml repeats them; a test keeps the two equal).
DEFAULTS = {
    'scene_file': 'config/scenes/fb_column.yaml',
    'model': '',                 # '' = the scene's
    'integrator': '',            # '' = the scene's
    'dt': 0.0,                   # 0 = the scene's, s
    'publish_rate_hz': 200.0,
    'real_time_factor': 1.0,     # 1 = wall clock, 0 = as fast as possible
    'use_sim_clock': True,
    'record_mcap': '',
    'record_rerun': '',
    'marker_rate_hz': 20.0,
    'prestrain_ramp_s': 0.05,    # s of simulation time
    'diagnostics_rate_hz': 2.0,
    'start_paused': False,       # start with the clock stopped; ~/set_running starts it
    'autostart': True,           # configure and activate at start-up (else: ~/change_state)
    'medium_speed_m_s': 1.0,     # wave speed of the host medium for ~/cmd/focus
    'field_rate_hz': 2.0,        # ~/field per wall second (arrays, after an impact); 0 = none
    'on_divergence': 'reset',    # reset: back to rest, keep publishing; pause: stop until resumed
}
DESCRIPTIONS = {
    'scene_file': 'scene YAML (absolute, relative to the working directory, or to the package)',
    'model': 'model override (auto, full3d, ...); empty = the scene value',
    'integrator': 'integrator.method override; empty = the scene value',
    'dt': 'integrator.dt override, s; 0 = the scene value',
    'publish_rate_hz': 'frames published per wall-clock second (timer rate)',
    'real_time_factor': 'simulated seconds per wall second; 0 = as fast as possible',
    'use_sim_clock': 'publish /clock with the simulation time',
    'record_mcap': 'rosbag2 bag folder (MCAP) to record every topic to: runs/x or runs/x.mcap '
                   '-> runs/x/x_0.mcap and runs/x/metadata.yaml; empty = none',
    'record_rerun': 'Rerun .rrd file to record to; empty = none',
    'marker_rate_hz': 'MarkerArray publications per wall second (<= publish_rate_hz)',
    'prestrain_ramp_s': 'simulation time over which a prestrain command is ramped, s',
    'diagnostics_rate_hz': '/diagnostics per wall second (with command counters; also at once '
                           'on a pause)',
    'start_paused': 'start with the simulation paused (impact, prestrain and focus commands '
                    'are rejected while paused); ~/set_running true starts the clock',
    'autostart': 'configure and activate the managed node at start-up; false: it waits '
                 'unconfigured for ~/change_state',
    'medium_speed_m_s': 'wave speed of the host medium below the bases (z > 0) for ~/cmd/focus, '
                        'm/s',
    'field_rate_hz': '~/field (32FC1 peak pressure map in the medium since the last impact of an '
                     'array) per wall second, computed only when subscribed or recorded; 0 = '
                     'none',
    'on_divergence': 'what a divergence of the simulation does: reset (back to the rest state, '
                     'the node keeps publishing) or pause (stop until ~/set_running true); '
                     'either way an ERROR log line and /diagnostics name it',
}
POSITIVE = ('publish_rate_hz', 'marker_rate_hz', 'diagnostics_rate_hz', 'medium_speed_m_s')
NON_NEGATIVE = ('real_time_factor', 'prestrain_ramp_s', 'dt', 'field_rate_hz')
# fixed once the node runs (the simulation and the recorders are built from them): a change is
# refused with this reason
READ_ONLY = ('scene_file', 'model', 'integrator', 'dt', 'record_mcap', 'record_rerun',
             'start_paused', 'autostart')
RESTART = 'is fixed while the node runs; restart the node with the new value'
# ranges the parameter descriptors show (FloatingPointRange; the upper ends are generous limits)
RANGES = {'publish_rate_hz': (1e-3, 10000.0), 'marker_rate_hz': (1e-3, 10000.0),
          'diagnostics_rate_hz': (1e-3, 1000.0), 'real_time_factor': (0.0, 1e6),
          'prestrain_ramp_s': (0.0, 1e3), 'dt': (0.0, 1.0), 'medium_speed_m_s': (1e-6, 1e5),
          'field_rate_hz': (0.0, 1000.0)}
# string parameters with a fixed set of values
CHOICES = {'on_divergence': ('reset', 'pause')}
# after a divergence that reset the simulation, /diagnostics stay at WARN naming it this long
# (wall seconds; the status right at the divergence is ERROR)
DIVERGENCE_HOLD_S = 10.0
# names the node accepts besides its own (rclpy's)
ROS_NAMES = ('use_sim_time', 'start_type_description_service')


def unknown_parameters(names):
    """ParameterError naming the parameters in ``names`` that the node does not have, listing the
    valid ones; None if there are none (QoS overrides and rclpy's own are valid)."""
    bad = sorted(n for n in names if n not in DEFAULTS and n not in ROS_NAMES
                 and not n.startswith('qos_overrides.'))
    if not bad:
        return None
    return ParameterError(f'unknown parameter{"s" if len(bad) > 1 else ""} '
                          f'{", ".join(bad)} (valid: {", ".join(DEFAULTS)})')


def refuse_undeclared(names, declared):
    """Raise rclpy's ``ParameterNotDeclaredException`` for the names in ``names`` that are not in
    ``declared`` (a change of a running node's parameters), its message naming them and listing the
    node's parameters (rclpy's own lists none: "undeclared parameter(s): []"). The service
    ``~/set_parameters`` returns the message as the reason."""
    bad = sorted({n for n in names if n not in declared})
    if not bad:
        return
    from rclpy.exceptions import ParameterNotDeclaredException
    message = (f'unknown parameter{"s" if len(bad) > 1 else ""} {", ".join(bad)} (valid: '
               f'{", ".join(DEFAULTS)})')

    class UnknownParameter(ParameterNotDeclaredException):
        def __str__(self):
            return message
    raise UnknownParameter(bad)


class ParameterError(ValueError):
    """A parameter value that cannot be used; the message names it."""


def find_config(path, name='scene_file'):
    """A config file given absolute, relative to the working directory, or to the package's data
    (the checkout, a colcon install, a pip install: :func:`tensegrity_ros.io.share.find_data`);
    ParameterError naming ``name`` and the places searched if none holds it."""
    from tensegrity_ros.io.share import find_data, searched
    found = find_data(path)
    if found is None:
        raise ParameterError(f'{name}: {str(path)!r} not found (looked in {searched()})')
    return found


def check_parameters(values):
    """Validate a dict of parameter values (names as in :data:`DEFAULTS`); integers are accepted
    for floating-point parameters. Returns the coerced dict."""
    values = dict(values)
    for name, default in DEFAULTS.items():
        v = values[name]
        if isinstance(default, float) and isinstance(v, int) and not isinstance(v, bool):
            values[name] = v = float(v)
        if type(v) is not type(default):
            raise ParameterError(f'{name}: expected {type(default).__name__}, got {v!r}')
    for name in POSITIVE:
        if not (math.isfinite(values[name]) and values[name] > 0):
            raise ParameterError(f'{name}: must be a positive number, got {values[name]!r}')
    for name in NON_NEGATIVE:
        if not (math.isfinite(values[name]) and values[name] >= 0):
            raise ParameterError(f'{name}: must be >= 0, got {values[name]!r}')
    for name, (lo, hi) in RANGES.items():
        if not lo <= values[name] <= hi:
            raise ParameterError(f'{name}: must be within [{lo:g}, {hi:g}], got {values[name]!r}')
    for name, valid in CHOICES.items():
        if values[name] not in valid:
            raise ParameterError(f'{name}: must be one of {", ".join(valid)}, got '
                                 f'{values[name]!r}')
    return values


def load_simulation(values):
    """The :class:`Simulation` the parameters describe, kernels compiled (one step, then reset)."""
    scene = Scene.load(find_config(values['scene_file']))
    sets = []
    if values['model']:
        sets.append(('model', values['model']))
    if values['integrator']:
        sets.append(('integrator.method', values['integrator']))
    if values['dt'] > 0:
        sets.append(('integrator.dt', values['dt']))
    if sets:
        scene = scene.with_overrides(sets)
    sim = simulation_for(scene)
    sim.advance(sim.dt)
    sim.reset()
    return sim


def measure_step_cost(sim, n=20):
    """Wall seconds per step of a freshly loaded ``sim``, timed on ``n`` steps; the simulation is
    reset afterwards (so only for a simulation at its initial state)."""
    t0 = time.perf_counter()
    try:
        sim.advance(n * sim.dt)
    except SimulationDiverged:
        pass
    cost = (time.perf_counter() - t0) / n
    sim.reset()
    return cost


def warm_commands(sim):
    """Load the compiled calls a prestrain command brings in, so that no tick after the first
    such command spends its time loading them from numba's cache (the pacer would take that for
    the cost of a step): the ramped step (the integrator's ramped twin,
    ``Simulation._ramped``, and on an array its ramped lanes), the plain steps after a ramp ends
    within an interval, and on an array the lane steps and the lane frame of columns that a
    command set apart. A ramp to the present prestrain over two steps (the second column's a
    billionth above it: two column simulations, which an array that steps as lanes steps as a
    lane group), one step, three (the ramp ends in the second), two more and a frame, then a
    reset (so only for a simulation at its initial state). Nothing where the scene has no
    prestrain to command."""
    if sim.prestrain is None:
        return
    goal = np.array(sim.prestrain_goal)
    goal[1:2] *= 1.0 + 1e-9
    try:
        sim.apply_prestrain(goal, ramp_s=2 * sim.dt)
        for n in (1, 3, 2):         # the ramp ends within the second call: its rest alone
            sim.advance(n * sim.dt)
        sim.frame()
    except SimulationDiverged:
        pass
    sim.reset()


def descriptor(name):
    """The ``ParameterDescriptor`` of parameter ``name``: its description, read-only or not, its
    range; types are checked by :func:`check_parameters` (dynamic typing)."""
    from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
    desc = ParameterDescriptor(description=DESCRIPTIONS[name], read_only=name in READ_ONLY,
                               dynamic_typing=True)
    if name in RANGES:
        lo, hi = RANGES[name]
        desc.floating_point_range = [FloatingPointRange(from_value=lo, to_value=hi)]
    if name in CHOICES:
        desc.additional_constraints = 'one of: ' + ', '.join(CHOICES[name])
    return desc


def refusal(current, changes):
    """Why a change of the running node's parameters (dict name -> new value) is refused, or
    None: a parameter fixed while the node runs, or a value the start-up check would refuse."""
    for name in changes:
        if name in READ_ONLY:
            return f'{name} {RESTART}'
    try:
        check_parameters(dict(current, **{n: v for n, v in changes.items() if n in current}))
    except ParameterError as exc:
        return str(exc)
    return None


LOG_THROTTLE_S = 1.0             # a repeated log line or event: at most once per this long


class ThrottledLog:
    """``log(kind, level, text)``: log ``text`` at ``level`` ('info', 'warning', 'error') unless a
    line of the same ``kind`` went out less than ``interval_s`` ago. (rclpy's own
    ``throttle_duration_sec`` inspects the caller's frame on every call, throttled or not: under
    a flood of commands that was a quarter of the node's time.)"""

    def __init__(self, logger, interval_s):
        self.logger, self.interval_s = logger, interval_s
        self.last = {}                 # kind -> wall time its line last went out

    def __call__(self, kind, level, text):
        now = time.monotonic()
        if now - self.last.get(kind, -math.inf) < self.interval_s:
            return
        self.last[kind] = now
        if level == 'error':           # one call site per severity (rclpy insists)
            self.logger.error(text)
        elif level == 'warning':
            self.logger.warning(text)
        else:
            self.logger.info(text)
