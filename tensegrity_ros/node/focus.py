"""The node's acoustic lens: ``~/cmd/focus`` plans, the planned impact, and ``~/field``.

A focus command plans one prestrain per column (:func:`solver.studies.lens.design`), ramps them
in over ``prestrain_ramp_s`` and then strikes every column at once; after an impact of an array
the base forces are recorded (:class:`solver.studies.lens_record.ImpactRecord`) so that the
arrivals and the field in the host medium can be reported (``/diagnostics``, ``~/field``).
"""
from __future__ import annotations

import json
import math

import numpy as np

from tensegrity_ros.msgs import messages
from tensegrity_ros.node.commands import CommandError, describe
from tensegrity_ros.node.stepping import step

FIELD_TOPIC = '~/field'


class Focus:
    """The lens part of node ``node``: ``current`` the last focus (dict: ``plan``, ``state``,
    ``impact_sim_time_s``, once measured ``measured``) or None; ``impact_at`` the simulation time
    of the planned impact while it is ahead; ``record`` the record of the last array impact."""

    def __init__(self, node):
        self.node = node
        self.current = self.impact_at = self.record = None
        self._last_field = -math.inf
        self._field_sent_t = None

    def reset(self):
        """A reset: the planned impact and the record are dropped, a ramping plan cancelled."""
        self.impact_at = self.record = None
        if self.current is not None and self.current['state'] == 'ramping':
            self.current['state'] = 'cancelled by reset'

    # -- the command ----------------------------------------------------------------------------
    def check(self, msg):
        """Validate a ``~/cmd/focus`` point (x along the array, z the depth below the bases, m)
        and plan it; returns the ``apply()`` that starts the ramp (raises CommandError)."""
        from solver import lens
        node, sim = self.node, self.node.sim
        x, z = float(msg.point.x), float(msg.point.z)
        if not (math.isfinite(x) and math.isfinite(z) and math.isfinite(msg.point.y)):
            raise CommandError(f'~/cmd/focus: the point must be finite, got '
                               f'({msg.point.x!r}, {msg.point.y!r}, {msg.point.z!r})')
        if sim.model.name == 'chain1d':
            raise CommandError('~/cmd/focus: the chain1d model cannot change its prestrain; use '
                               'model auto, full3d or sym3d')
        v0 = float(sim.scene.loading.impact.v0)
        if not v0 > 0:
            raise CommandError('~/cmd/focus: the scene has no impact velocity '
                               '(loading.impact.v0 > 0) to plan for')
        node.intake.refuse_if_paused('~/cmd/focus')        # before the (costly) plan
        speed = node.params['medium_speed_m_s']
        try:
            plan = lens.design(sim.scene, (x, z), speed, v0)
        except (lens.LensError, KeyError) as exc:
            raise CommandError(f'~/cmd/focus: {exc}') from None
        p = [c['prestrain'] for c in plan.columns]

        def apply():
            ramp = node.params['prestrain_ramp_s']
            sim.apply_prestrain(p, ramp_s=ramp)
            self.impact_at = sim.t + ramp
            self.current = {'plan': plan.as_dict(), 'state': 'ramping',
                            'impact_sim_time_s': node.clock_time(self.impact_at)}
            if ramp == 0:
                self.impact()
            return (f'focus ({x:g}, {z:g}) m at C = {speed:g} m/s: prestrain per column '
                    f'{describe(np.array(p))} over {ramp:g} s, then impact v0 = {v0:g} m/s on '
                    f'every column')
        return apply

    def steps_until_impact(self, n):
        """At most ``n`` steps, so that the run lands exactly on a planned impact (made when it
        is due; then ``None``: step as paced). A fraction of a step (``n`` < 1) becomes one whole
        step while an impact is planned (:meth:`advance` takes whole steps for a record)."""
        if 0 < n < 1 and self.impact_at is not None:
            n = 1
        if self.impact_at is None:
            return n
        left = max(0, round((self.impact_at - self.node.sim.t) / self.node.sim.dt))
        if left == 0:
            self.impact()
            return None
        return min(n, left)

    def impact(self):
        """The planned impact of a focus: every column at once."""
        node, sim = self.node, self.node.sim
        self.impact_at = None
        v0 = self.current['plan']['v0']
        added = sim.apply_impact(v0)
        self.current['state'] = 'impacted'
        self.current['impact_sim_time_s'] = float(node.clock_time())
        self.start_record(tuple(self.current['plan']['focus_m']))
        detail = f'focus impact v0 = {v0:g} m/s on every column, kinetic energy +{added:.3g} J'
        node.log('focus impact', 'info', f'~/cmd/focus: {detail}')
        node.event(f'~/cmd/focus: {detail}')

    # -- the record and the field ---------------------------------------------------------------
    def start_record(self, focus=None):
        """After an impact of an array: record its base forces for the scene's ``run.t_end``
        (always for a focus, whose arrivals /diagnostics report; for another impact only while
        ``field_rate_hz`` > 0 and someone listens to ``~/field`` or records)."""
        from solver import ImpactRecord, is_array
        node = self.node
        self.record = None
        if not is_array(node.sim.scene) or (focus is None and (
                node.params['field_rate_hz'] <= 0 or not self._field_wanted())):
            return
        self.record = ImpactRecord(node.sim, node.params['medium_speed_m_s'],
                                   float(node.sim.scene.run.t_end), focus)
        self._last_field = -math.inf
        self._field_sent_t = None

    def _field_wanted(self):
        sinks = self.node.sinks
        return (sinks.has('message') or sinks.has('field')
                or self.node.pubs[FIELD_TOPIC].get_subscription_count() > 0)

    def advance(self, n):
        """Advance the simulation ``n`` steps (``n`` < 1: one step shortened to that fraction),
        sampling the base forces of a record (whole steps: a fraction becomes one); returns the
        steps taken."""
        if self.record is not None:
            n = max(int(n), 1)
            self.record.advance(self.node.sim, n)
        else:
            step(self.node.sim, n)
        return n

    def after_steps(self, now):
        """Once per stepping tick with a record: the focus figures when it is complete, the
        field when it is due (``field_rate_hz``) and someone listens or records."""
        rec = self.record
        if rec is None:
            return
        if rec.focus is not None and rec.done and self.current is not None \
                and 'measured' not in self.current:
            plan = self.current['plan']
            self.current['measured'] = rec.measure([c['target_s'] for c in plan['columns']])
        rate = self.node.params['field_rate_hz']
        if rate > 0 and now - self._last_field >= 1.0 / rate and self._field_wanted():
            self._last_field = now
            self._publish_field(rec)

    def _publish_field(self, rec):
        """``~/field``: the peak pressure map since the impact (model units, 32FC1); the field
        sinks get it with the pressure now. A non-finite map is not published."""
        node = self.node
        peak = rec.peak_map()
        if peak is None:
            return
        stamp = messages.sim_stamp(node.clock_time(rec.peak_time))
        try:
            msg = messages.field_image(peak, stamp)
        except ValueError as exc:
            node.log('field', 'error', f'~/field: {exc}; not published')
            return
        node.pubs[FIELD_TOPIC].publish(msg)
        node.sinks.message(node.topics[FIELD_TOPIC], msg, messages.stamp_to_ns(stamp))
        if node.sinks.has('field') and rec.peak_time != self._field_sent_t:   # each time once
            self._field_sent_t = rec.peak_time
            now = rec.pressure_now()
            node.sinks.field(float(node.clock_time(rec.peak_time)), peak,
                             now if np.isfinite(now).all() else None)

    # -- /diagnostics ---------------------------------------------------------------------------
    def values(self):
        """The focus plan as /diagnostics values (texts; JSON lists per column)."""
        f = self.current
        if f is None:
            return {'focus': 'none'}
        plan = f['plan']
        cols = plan['columns']
        return {'focus': f['state'], 'focus_x_m': float(plan['focus_m'][0]),
                'focus_z_m': float(plan['focus_m'][1]),
                'focus_medium_speed_m_s': float(plan['medium_speed_m_s']),
                'focus_v0': float(plan['v0']), 'focus_t0_s': float(plan['t0_s']),
                'focus_impact_sim_time_s': float(f['impact_sim_time_s']),
                'focus_prestrain': json.dumps([c['prestrain'] for c in cols]),
                'focus_arrival_target_s': json.dumps([c['target_s'] for c in cols]),
                'focus_arrival_predicted_s': json.dumps([c['predicted_s'] for c in cols]),
                **measured_values(f.get('measured'))}


def measured_values(m):
    """The figures of a focus measured on the node's own run (``focus_measured`` true once its
    record is complete): per column the simulated arrival and its residual (JSON lists, s after
    the impact; a column without a pulse as null) and the peak pressure at F."""
    if m is None:
        return {'focus_measured': 'false'}

    def finite(v):
        return [x if math.isfinite(x) else None for x in v]
    return {'focus_measured': 'true',
            'focus_arrival_simulated_s': json.dumps(finite(m['simulated_s'])),
            'focus_residual_s': json.dumps(finite(m['residual_s'])),
            'focus_peak_pressure': (float(m['peak_pressure'])
                                    if math.isfinite(m['peak_pressure']) else -1.0)}
