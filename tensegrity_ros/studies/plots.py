"""Pictures of a run (matplotlib, Agg backend: works headless)."""
from __future__ import annotations

import numpy as np


LINEAR_STRAIN = 0.01   # symmetric-log scales are linear within +-1 % strain (as in Rerun)
SYMLOG_FROM = 1.0      # a run whose |strain| reaches this is drawn on symmetric-log scales


def strain_wave(rec, path, title='', column=0, snapshots=(0.1, 0.3, 0.5, 0.7, 0.9)):
    """Two panels: strain against prism index at several times (like the paper's figures) and a
    prism-by-time heat map of the whole wave. Writes a PNG to ``path``; returns ``path``.
    Where |strain| reaches :data:`SYMLOG_FROM` (a crushing impact, a train piling up) both
    panels use a symmetric-log scale, linear within :data:`LINEAR_STRAIN`, so that a leading
    pulse of 0.1 stays visible beside a crushed prism."""
    import matplotlib.pyplot as plt
    fig = strain_wave_figure(rec, title, column, snapshots)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def strain_wave_figure(rec, title='', column=0, snapshots=(0.1, 0.3, 0.5, 0.7, 0.9)):
    """The figure of :func:`strain_wave`. Snapshot times past the run are left out (the last
    frame stands in if none is left); points carry markers, so that a single prism shows too."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    strain = rec.strain[:, column]
    n_prisms = strain.shape[1]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.5), constrained_layout=True)
    times = [t for t in snapshots if t <= rec.times[-1]] or [rec.times[-1]]
    for t in times:
        k = int(np.argmin(np.abs(rec.times - t)))
        ax1.plot(np.arange(1, n_prisms + 1), strain[k], marker='o', markersize=3,
                 label=f't = {rec.times[k]:.2f} s')
    ax1.set_xlabel('prism (1 = clamped end, %d = impacted end)' % n_prisms if n_prisms > 1
                   else 'prism (a single prism: clamped below, impacted on top)')
    ax1.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax1.set_ylabel('axial strain (h - h0) / h')
    ax1.legend(fontsize=8)
    ax1.grid(alpha=0.3)
    lim = float(np.max(np.abs(strain))) or 1.0
    log = lim >= SYMLOG_FROM
    if log:
        from matplotlib.colors import SymLogNorm
        ax1.set_yscale('symlog', linthresh=LINEAR_STRAIN)
        ax1.set_ylabel(f'axial strain (h - h0) / h, symmetric log (linear within '
                       f'+-{LINEAR_STRAIN:g})')
        norm = SymLogNorm(LINEAR_STRAIN, vmin=-lim, vmax=lim, base=10)
    else:
        from matplotlib.colors import Normalize
        norm = Normalize(-lim, lim)
    im = ax2.imshow(strain.T, aspect='auto', origin='lower', cmap='RdBu', norm=norm,
                    extent=(rec.times[0], rec.times[-1], 0.5, n_prisms + 0.5))
    fig.colorbar(im, ax=ax2, label='strain, symmetric log' if log else 'strain')
    ax2.set_xlabel('time (s)')
    ax2.set_ylabel('prism')
    ax2.yaxis.set_major_locator(MaxNLocator(integer=True))
    if n_prisms == 1:
        ax2.set_yticks([1])
    _mark_front(ax2, rec.times, strain)
    fig.suptitle(title)
    return fig


def _mark_front(ax, times, strain):
    """On the heat map ``ax`` (prism 1 at the clamped end): where the front reaches the two
    stations of the front figures (solver.analysis.front.front_stations, at
    FRONT_LEVEL), joined by a line labelled with its time-of-flight speed in prisms per second;
    nothing where it does not reach both."""
    from solver import FRONT_LEVEL, front_arrivals
    n = strain.shape[1]
    front = front_arrivals(times, np.asarray(strain)[:, ::-1])
    if front is None:
        return
    stations, arrivals, _ = front
    if not all(np.isfinite(arrivals)) or arrivals[1] <= arrivals[0]:
        return
    rows = [n - p for p in stations]            # prism numbers of the plot, 1 = clamped end
    rate = (stations[1] - stations[0]) / (arrivals[1] - arrivals[0])
    ax.plot(arrivals, rows, 'k--', marker='x', markersize=7, linewidth=1,
            label=f'front at {100 * FRONT_LEVEL:g} % strain: {rate:.1f} prisms/s')
    ax.legend(fontsize=8, loc='upper right')


def lens_title(result, spacing):
    """The title of :func:`lens_field`: medium, focus, focal gain and how far the field peaks from
    the focus, in column spacings (``spacing``, m) and in m."""
    X, Z = result['focus_m']
    gain = result['focal_gain']
    peak, lateral = result['peak_offset_spacings'], result['lateral_offset_spacings']
    return (f"peak pressure in the medium ({result['dims']}D), C = "
            f"{result['medium_speed_m_s']:g} m/s, focus ({X:g}, {Z:g}) m: focal gain "
            f"{'n/a' if gain is None else f'{gain:.2f}'}\nfield peak {peak:.2f} column spacings "
            f"({peak * spacing:.2g} m) from the focus, across the focal depth {lateral:.2f} "
            f"spacings ({lateral * spacing:.2g} m)")


def lens_field(result, path):
    """The peak pressure in the medium (the model of :mod:`solver.analysis.field`) of the designed
    array next to the same array at uniform prestrain, the bases and the focus marked, and the peak
    pressure of both across the focal depth with one column spacing either side of the focus
    shaded. ``result``: the dict of ``tensegrity lens`` (with its ``_field`` maps). Writes a PNG;
    returns ``path``."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    f = result['_field']
    xs, zs = f['x'], f['z']
    X, Z = result['focus_m']
    top = float(max(f['peak'].max(), f['uniform'].max())) or 1.0
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.8), constrained_layout=True,
                             gridspec_kw={'width_ratios': [1, 1, 0.9]})
    uniform = f"uniform prestrain {result['uniform_prestrain']:.4f}"
    for ax, key, name in ((axes[0], 'peak', 'designed prestrains'), (axes[1], 'uniform', uniform)):
        im = ax.imshow(f[key], origin='upper', aspect='auto', cmap='magma', vmin=0, vmax=top,
                       extent=(xs[0], xs[-1], zs[-1], zs[0]))
        ax.plot(f['bases'], np.zeros_like(f['bases']) + zs[0], 'v', color='cyan', ms=7,
                label='column bases')
        ax.plot([X], [Z], '+', color='lime', ms=14, mew=2, label='focus')
        if key == 'peak':
            ax.plot(*result['peak_xz_m'], 'x', color='white', ms=9, mew=2, label='field peak')
        ax.set_xlabel('x (m)')
        ax.set_title(name)
    axes[1].sharey(axes[0])
    axes[0].set_ylabel('depth z (m)')
    axes[0].legend(loc='lower left', fontsize=8)
    fig.colorbar(im, ax=axes[:2], label='peak pressure (model units)')
    ax = axes[2]
    s = f['spacing']
    ax.axvspan(X - s, X + s, color='lime', alpha=0.15, label='focus +- one spacing')
    ax.plot(f['lateral_x'], f['lateral'], color='C3', label='designed')
    ax.plot(f['lateral_x'], f['lateral_uniform'], color='C0', ls='--', label='uniform')
    ax.axvline(X, color='green', lw=0.8)
    ax.set_xlabel('x (m)')
    ax.set_ylabel('peak pressure (model units)')
    ax.set_title(f'across the focal depth z = {Z:g} m')
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.suptitle(lens_title(result, s))
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


# units of the scene keys a sweep varies (SI) and of the summary's figures
D = 'dimensionless'
KEY_UNITS = {
    'loading.impact.v0': 'm/s', 'loading.impact.striker_mass': 'kg',
    'loading.impact.contact_stiffness': 'N/m', 'loading.impact.period': 's',
    'loading.gravity': 'm/s^2', 'prestrain': D, 'structure.radius': 'm', 'structure.h0': 'm',
    'structure.column_spacing': 'm', 'structure.node_mass': 'kg', 'structure.kappa': D,
    'structure.n_prisms': 'prisms', 'materials.cable_E': 'Pa', 'materials.cable_radius': 'm',
    'materials.unit_mass': 'kg', 'materials.bar_mass': 'kg', 'materials.bar_mass_fraction': D,
    'materials.end_mass': 'kg', 'materials.cable_damping': 'N s/m',
    'materials.cable_damping_ratio': D, 'materials.bar_radius': 'm', 'materials.bar_E': 'Pa',
    'materials.bar_poisson': D, 'integrator.dt': 's', 'integrator.rtol': D,
    'run.t_end': 's', 'run.output_dt': 's', 'contact.stiffness': 'N/m', 'contact.tolerance': 'h0',
    'lens.prestrain_min': D, 'lens.prestrain_max': D,
    'pulse.amplitude': 'strain, dimensionless', 'pulse.amplitude_median': 'strain, dimensionless',
    'pulse.amplitude_min': 'strain, dimensionless', 'pulse.amplitude_max': 'strain, dimensionless',
    'pulse.amplitude_passage_max': 'strain, dimensionless',
    'pulse.front_amplitude': 'strain, dimensionless', 'energy_drift_rel': '1/s',
    'pulse.momentum_strain': 'kg m/s', 'pulse.momentum_nodes': 'kg m/s',
    'pulse.momentum_column': 'kg m/s', 'pulse.momentum_ratio': D, 'pulse.momentum_share': D,
    'energy_balance_error': D, 'constraint_error_rel': D, 'real_time_factor': 'x real time',
}
SUFFIX_UNITS = (('_m_s', 'm/s'), ('_prisms', 'prisms'), ('_s', 's'), ('_N', 'N'), ('_J', 'J'),
                ('_hz', 'Hz'))


def axis_label(name):
    """``name`` (a scene key or a figure of the summary) with its unit: ``loading.impact.v0
    (m/s)``, ``prestrain (dimensionless)``; a name of no known unit as it is."""
    unit = KEY_UNITS.get(name) or next((u for suffix, u in SUFFIX_UNITS if name.endswith(suffix)),
                                       None)
    if unit is None:
        return name
    return f'{name} ({unit})'


def sweep_map(rows, keys, figure, path):
    """A heat map of ``figure`` over the first two swept ``keys`` (a line over one key; a scatter
    for scattered samples), diverged and failed points marked with a cross. Returns ``path``."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    bad = [r for r in rows if r.get('status') != 'ok']

    def val(r):
        v = r.get(figure)
        return np.nan if v is None else float(v)

    def axis_values(k):
        vals = []
        for r in rows:
            if r[k] not in vals:
                vals.append(r[k])
        numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in vals)
        return (sorted(vals) if numeric else vals), numeric

    if len(keys) == 1:
        k = keys[0]
        xs, numeric = axis_values(k)
        pos = {v: (v if numeric else i) for i, v in enumerate(xs)}
        good = sorted((pos[r[k]], val(r)) for r in rows if r.get('status') == 'ok')
        ax.plot([g[0] for g in good], [g[1] for g in good], 'o-', label=figure)
        for r in bad:
            ax.axvline(pos[r[k]], color='red', ls=':', lw=1)
            ax.plot(pos[r[k]], min((g[1] for g in good if np.isfinite(g[1])), default=0.0),
                    'rx', ms=9)
        if not numeric:
            ax.set_xticks(range(len(xs)), [str(v) for v in xs])
        ax.set_xlabel(axis_label(k))
        ax.set_ylabel(axis_label(figure))
    else:
        kx, ky = keys[0], keys[1]
        xs, nx = axis_values(kx)
        ys, ny = axis_values(ky)
        if len(xs) * len(ys) <= len(rows) or not (nx and ny):
            grid = np.full((len(ys), len(xs)), np.nan)
            for r in rows:
                if r.get('status') == 'ok':
                    grid[ys.index(r[ky]), xs.index(r[kx])] = val(r)
            im = ax.imshow(grid, origin='lower', aspect='auto', cmap='viridis',
                           interpolation='nearest')
            for r in bad:
                ax.plot(xs.index(r[kx]), ys.index(r[ky]), 'rx', ms=10, mew=2)
            ax.set_xticks(range(len(xs)), [f'{v:.4g}' if nx else str(v) for v in xs],
                          rotation=45 if len(xs) > 6 else 0)
            ax.set_yticks(range(len(ys)), [f'{v:.4g}' if ny else str(v) for v in ys])
        else:                              # scattered (Latin-hypercube) samples
            good = [r for r in rows if r.get('status') == 'ok' and np.isfinite(val(r))]
            none = [r for r in rows if r.get('status') == 'ok' and not np.isfinite(val(r))]
            im = ax.scatter([r[kx] for r in good], [r[ky] for r in good],
                            c=[val(r) for r in good], cmap='viridis')
            ax.scatter([r[kx] for r in none], [r[ky] for r in none], facecolors='none',
                       edgecolors='grey', label=f'no {figure}')
            ax.plot([r[kx] for r in bad], [r[ky] for r in bad], 'rx', ms=10, mew=2)
        fig.colorbar(im, ax=ax, label=axis_label(figure))
        ax.set_xlabel(axis_label(kx))
        ax.set_ylabel(axis_label(ky))
    title = f'{figure}' + (f' ({len(bad)} diverged or failed: x)' if bad else '')
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return str(path)
