"""The node's record of an array's base forces after an impact and the field in the host medium it
gives (:mod:`solver.analysis.field`): what ``~/field`` publishes, what a Rerun recording shows of
the field, and what ``/diagnostics`` report of a focus once its pulses have arrived. No ROS
imports.
"""
from __future__ import annotations

import numpy as np

from solver.analysis import field

from solver.studies import lens
from solver.analysis.support import pulse_arrival

IMAGE_SHAPE = (48, 64)          # (depth, x) pixels of ~/field (solver.analysis.field.image_grid)


def grid_extent(xs, zs):
    """``(x0, x1, z0, z1)`` m: the outer cell edges of a grid of cell centres."""
    dx, dz = xs[1] - xs[0], zs[1] - zs[0]
    return (float(xs[0] - dx / 2), float(xs[-1] + dx / 2), float(zs[0] - dz / 2),
            float(zs[-1] + dz / 2))


def is_array(scene):
    """A scene whose columns can be a lens: the column builder, two columns or more."""
    return scene.structure.builder == 'column' and scene.structure.n_columns >= 2


def image_grid(scene):
    """Cell centres ``(xs, zs)`` m of the ``~/field`` images of an array scene."""
    return field.image_grid(lens.base_x(scene), n_x=IMAGE_SHAPE[1], n_z=IMAGE_SHAPE[0])


class ImpactRecord:
    """The base force of every column every :data:`solver.studies.lens.SAMPLE_S` (whole steps) from
    an impact (the simulation's time now) for ``duration_s`` s, and the peak pressure map in a
    medium of speed ``speed`` m/s on :func:`image_grid` (2D spreading), grown from the record when
    asked (:meth:`peak_map`). ``focus``: ``(X, Z)`` m of a focus plan, whose figures
    :meth:`measure` gives once the record is complete."""

    def __init__(self, sim, speed, duration_s, focus=None):
        self.every = max(1, int(round(lens.SAMPLE_S / sim.dt)))
        self.dt = self.every * sim.dt
        self.n_max = int(round(duration_s / self.dt)) + 1
        self.t0 = float(sim.t)
        self.times = [self.t0]
        self.forces = [np.array(sim.base_force(), dtype=np.float64)]
        self.to_next = self.every
        self.speed = float(speed)
        self.focus = focus
        self.base_x = lens.base_x(sim.scene)
        self.xs, self.zs = image_grid(sim.scene)
        X, Z = np.meshgrid(self.xs, self.zs)
        self._peak = field.PeakMap(np.stack([X.ravel(), Z.ravel()], axis=1), self.base_x,
                                   self.speed, self.dt)
        self._fed = 0

    @property
    def done(self):
        return len(self.times) >= self.n_max

    def advance(self, sim, n):
        """Advance ``sim`` by ``n`` steps, sampling the base force on the way (the steps after
        the record is complete in one call)."""
        while n > 0 and not self.done:
            k = min(n, self.to_next)
            sim.advance(k * sim.dt)
            n -= k
            self.to_next -= k
            if self.to_next == 0:
                self.times.append(float(sim.t))
                self.forces.append(np.array(sim.base_force(), dtype=np.float64))
                self.to_next = self.every
        if n > 0:
            sim.advance(n * sim.dt)

    def peak_map(self):
        """``max_t p`` (n_z, n_x) over the record so far, or None before its first sample is
        taken (a sample is taken once the next one is in; the last when the record is
        complete)."""
        if self._fed < len(self.forces):
            self._peak.extend(np.array(self.forces[self._fed:]))
            self._fed = len(self.forces)
        if self.done and self._peak.count < self._fed:
            self._peak.finish()
        if self._peak.count == 0:
            return None
        return self._peak.peak.reshape(len(self.zs), len(self.xs))

    @property
    def peak_time(self):
        """Simulation time s up to which :meth:`peak_map` holds the field (after the record's
        end, once complete: until the end has passed the whole grid)."""
        return self.t0 + (max(self._peak.count, 1) - 1) * self.dt

    def pressure_now(self):
        """``p(r, t)`` (n_z, n_x) at :attr:`peak_time`."""
        t, b = np.array(self.times), np.array(self.forces)
        rates = field.source_rates(t, b) if len(t) > 1 else np.zeros_like(b)
        return field.frames(self.xs, self.zs, t, rates, self.base_x, self.speed,
                            [self.peak_time])[0]

    def measure(self, targets):
        """The figures of a complete record of a focus: per column the arrival at the base
        (:func:`solver.analysis.support.pulse_arrival`, as the design times it; the record's first
        sample as rest) and its residual against ``targets`` (s after the impact, the plan's delay
        law), and the peak pressure at the focus (``max_t p`` at F, model units)."""
        t, b = np.array(self.times) - self.t0, np.array(self.forces)
        arrivals = [pulse_arrival(t, b[:, c]).time_s for c in range(b.shape[1])]
        X, Z = self.focus
        at, _ = field.peak_map([X], [Z], t, field.source_rates(t, b), self.base_x, self.speed)
        return {'simulated_s': [float(a) for a in arrivals],
                'residual_s': [float(a - T) for a, T in zip(arrivals, targets)],
                'peak_pressure': float(at[0, 0])}
