"""The report of ``tensegrity lens``: a focusing design, its check run, the field in the host
medium at and around the focus, its focal gain against a uniform array, and (optionally) a Rerun
recording of the check run with the field over ``sim_time``."""
from __future__ import annotations

import numpy as np


def recorder(scene, path):
    """A Rerun recorder of the lens array with the field grid of :func:`field_grid`."""
    from solver import lens
    from solver import build_network

    from solver import grid_extent
    from tensegrity_ros.io.rerun_sink import RerunRecorder
    xs, zs = field_grid(lens.base_x(scene))
    return RerunRecorder(build_network(scene), path, field_grid=grid_extent(xs, zs))


def field_grid(base_x):
    """The grid of the field images: that of the node's ``~/field`` (lens_record.IMAGE_SHAPE)."""
    from solver import field

    from solver import IMAGE_SHAPE
    return field.image_grid(base_x, n_x=IMAGE_SHAPE[1], n_z=IMAGE_SHAPE[0])


def result(scene, focus, speed, v0, dims=2, recorder=None):
    """The plan, its check, the field's figures at the focus (solver.analysis.field.focus_report)
    and the focal gain of a focus, the maps for the plot (a dict). ``recorder``: a RerunRecorder of
    the array (:func:`recorder`) that gets the check run's frames and the field over time."""
    from solver import field

    from solver import lens
    plan = lens.design(scene, focus, speed, v0)
    frame_dt = scene.run.output_dt
    t, b = lens.check(scene, plan, None if recorder is None else recorder.frame, frame_dt)
    p_uniform = float(np.mean([c['prestrain'] for c in plan.columns]))
    tu, bu, _ = lens.simulate(scene, np.full(len(plan.columns), p_uniform), v0)
    xs_b = lens.base_x(scene)
    spacing = scene.structure.column_spacing
    rep = field.focus_report(t, b, xs_b, focus, speed, spacing, dims)
    rep_u = field.focus_report(tu, bu, xs_b, focus, speed, spacing, dims)
    X, Z = focus
    span = max(xs_b[-1] - xs_b[0], spacing)
    xs = np.linspace(min(xs_b[0] - 0.25 * span, X - 0.1 * span),
                     max(xs_b[-1] + 0.25 * span, X + 0.1 * span), 121)
    zs = np.linspace(0.0, max(1.5 * span, 1.5 * Z), 91)[1:]
    pk, _ = field.peak_map(xs, zs, t, field.source_rates(t, b), xs_b, speed, dims)
    pu, _ = field.peak_map(xs, zs, tu, field.source_rates(tu, bu), xs_b, speed, dims)
    if recorder is not None:
        record_field(recorder, t, b, xs_b, speed, dims, frame_dt)
        recorder.command(0.0, f'focus ({X:g}, {Z:g}) m at C = {speed:g} m/s: impact v0 = '
                              f'{v0:g} m/s on every column at once')
    rise = np.array([c['rise_s'] for c in plan.columns])
    result = plan.as_dict()
    result.update(dims=dims, uniform_prestrain=p_uniform,
                  focal_gain=rep['p_focus'] / rep_u['p_focus'] if rep_u['p_focus'] > 0
                  else None,
                  p_focus=rep['p_focus'], p_focus_uniform=rep_u['p_focus'],
                  lateral_peak_x_m=rep['lateral_peak_x_m'],
                  lateral_offset_spacings=rep['lateral_offset_spacings'],
                  axial_peak_z_m=rep['axial_peak_z_m'], peak_xz_m=list(rep['peak_xz_m']),
                  peak_offset_spacings=rep['peak_offset_spacings'],
                  rise_mean_s=float(np.mean(rise)),
                  cached_map=plan.cached,
                  _field={'x': xs, 'z': zs, 'peak': pk, 'uniform': pu, 'bases': xs_b,
                          'lateral_x': rep['lateral_x_m'], 'lateral': rep['lateral_peak'],
                          'lateral_uniform': rep_u['lateral_peak'], 'spacing': spacing})
    return result


def record_field(recorder, t, b, base_x, speed, dims, frame_dt):
    """The field over ``sim_time`` into ``recorder``: at every frame time the peak pressure up to
    then (solver.analysis.field.PeakMap on the recorded base forces) and the pressure then, and
    once more when the record's end has passed the whole grid, all over the largest peak
    pressure."""
    from solver import field
    xs, zs = field_grid(base_x)
    X, Z = np.meshgrid(xs, zs)
    pts = np.stack([X.ravel(), Z.ravel()], axis=1)
    dt = float(t[1] - t[0])
    every = max(1, int(round(frame_dt / dt)))
    stops = list(range(0, len(t), every))
    peaks = []
    pm = field.PeakMap(pts, base_x, speed, dt, dims)
    done = 0
    for k in stops:
        pm.extend(b[done:k + 1])
        done = k + 1
        peaks.append(np.maximum(pm.peak, 0.0).reshape(X.shape))
    pm.extend(b[done:])
    pm.finish()                    # and after the record, until its end has passed the grid
    t_last = float(t[0] + (pm.count - 1) * dt)
    peaks.append(np.maximum(pm.peak, 0.0).reshape(X.shape))
    scale = float(max(p.max() for p in peaks)) or 1.0
    rates = field.source_rates(t, b)
    at = np.append(t[stops], t_last)
    now = field.frames(xs, zs, t, rates, base_x, speed, at, dims)
    for when, peak, p in zip(at, peaks, now):
        recorder.field(float(when), peak, p, scale)


def format_lines(r):
    """The printed report of :func:`result`, line by line."""
    X, Z = r['focus_m']
    lines = [f"lens: focus ({X:g}, {Z:g}) m, medium {r['medium_speed_m_s']:g} m/s, "
             f"v0 = {r['v0']:g} m/s, T0 = {r['t0_s']:.4f} s"
             + (' (arrival map from the cache)' if r['cached_map'] else ''),
             '  column   x m    prestrain   target s   predicted s   simulated s   residual ms']
    for c in r['columns']:
        lines.append(f"  {c['column']:6d} {c['x_m']:6.3f} {c['prestrain']:11.5f} "
                     f"{c['target_s']:10.4f} {c['predicted_s']:13.4f} {c['simulated_s']:13.4f} "
                     f"{1e3 * c['residual_s']:13.3f}")
    lines.append(f"  the delay law spans {1e3 * r['law_span_s']:.1f} ms of the "
                 f"{1e3 * r['map_span_s']:.1f} ms the prestrain range gives; the pulses rise "
                 f"over {1e3 * r['rise_mean_s']:.0f} ms (rate width at half height)")
    gain = r['focal_gain']
    lines.append(f"  field ({r['dims']}D): across depth {Z:g} m the peak lies at x = "
                 f"{r['lateral_peak_x_m']:.3f} m ({r['lateral_offset_spacings']:.2f} column "
                 f"spacings from X); along x = {X:g} m at depth {r['axial_peak_z_m']:.3f} m")
    px, pz = r['peak_xz_m']
    lines.append(f"  the field's peak down to depth {2 * Z:g} m: ({px:.3f}, {pz:.3f}) m, "
                 f"{r['peak_offset_spacings']:.2f} column spacings from F")
    lines.append(f"  focal gain {'n/a' if gain is None else f'{gain:.3f}'} (peak at F against "
                 f"the same array at uniform prestrain {r['uniform_prestrain']:.5f})")
    for key in ('plot', 'rerun'):
        if r.get(key):
            lines.append(f"  {key}: {r[key]}")
    return lines
