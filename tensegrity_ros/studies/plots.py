"""Pictures of a run (matplotlib, Agg backend: works headless)."""
from __future__ import annotations

import numpy as np


def strain_wave(rec, path, title='', column=0, snapshots=(0.1, 0.3, 0.5, 0.7, 0.9)):
    """Two panels: strain against prism index at several times (like the paper's figures) and a
    prism-by-time heat map of the whole wave. Writes a PNG to ``path``; returns ``path``."""
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
    im = ax2.imshow(strain.T, aspect='auto', origin='lower', cmap='RdBu', vmin=-lim, vmax=lim,
                    extent=(rec.times[0], rec.times[-1], 0.5, n_prisms + 0.5))
    fig.colorbar(im, ax=ax2, label='strain')
    ax2.set_xlabel('time (s)')
    ax2.set_ylabel('prism')
    ax2.yaxis.set_major_locator(MaxNLocator(integer=True))
    if n_prisms == 1:
        ax2.set_yticks([1])
    fig.suptitle(title)
    return fig


def lens_field(result, path):
    """The peak pressure in the medium (the model of :mod:`solver.analysis.field`) of the designed
    array
    next to the same array at uniform prestrain, the bases and the focus marked, and the peak
    pressure of both across the focal depth with one column spacing either side of the focus
    shaded. ``result``: the dict of ``tensegrity lens`` (with its ``_field`` maps). Writes a
    PNG; returns ``path``."""
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
    gain = result['focal_gain']
    fig.suptitle(f"peak pressure in the medium ({result['dims']}D), C = "
                 f"{result['medium_speed_m_s']:g} m/s, focus ({X:g}, {Z:g}) m: focal gain "
                 f"{'n/a' if gain is None else f'{gain:.2f}'}; field peak "
                 f"{result['peak_offset_spacings']:.2f} spacings from the focus, across the "
                 f"focal depth {result['lateral_offset_spacings']:.2f}")
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
