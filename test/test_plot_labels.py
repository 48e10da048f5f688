"""Units on the axes of sweep plots and in the lens plot's title."""
import pytest

from tensegrity_ros.studies import plots
from tensegrity_ros.studies.table import FIGURES


@pytest.mark.parametrize('name,unit', [
    ('loading.impact.v0', 'm/s'), ('prestrain', 'dimensionless'), ('structure.radius', 'm'),
    ('integrator.dt', 's'), ('pulse.speed_m_s', 'm/s'), ('pulse.arrival_time_s', 's'),
    ('pulse.amplitude', 'strain, dimensionless'), ('pulse.width_half_prisms', 'prisms'),
])
def test_axis_labels_carry_units(name, unit):
    assert plots.axis_label(name) == f'{name} ({unit})'


def test_every_figure_and_unit_key_is_real():
    """Every figure a sweep can plot has a unit; every key of the unit table is a scene key or a
    figure (a misspelt key would never match)."""
    from solver.build.scene import DEFAULTS
    assert all(plots.axis_label(f).endswith(')') for f in FIGURES), \
        [f for f in FIGURES if not plots.axis_label(f).endswith(')')]

    def scene_key(key):
        node = DEFAULTS
        for part in key.split('.'):
            if not isinstance(node, dict) or part not in node:
                return key == 'structure.node_mass'        # the explicit builder's
            node = node[part]
        return True
    summary = set(FIGURES) | {'energy_balance_error', 'real_time_factor'}
    bad = [k for k in plots.KEY_UNITS if k not in summary and not scene_key(k)]
    assert not bad, bad


def test_sweep_plot_axes_name_units(tmp_path, monkeypatch):
    import matplotlib.pyplot as plt
    figs = []
    monkeypatch.setattr(plt, 'close', figs.append)
    rows = [{'loading.impact.v0': v, 'prestrain': p, 'status': 'ok', 'pulse.speed_m_s': v + p}
            for v in (0.1, 0.15) for p in (0.002, 0.003)]
    plots.sweep_map(rows, ['loading.impact.v0', 'prestrain'], 'pulse.speed_m_s',
                    tmp_path / 'map.png')
    ax = figs[0].axes[0]
    assert ax.get_xlabel() == 'loading.impact.v0 (m/s)'
    assert ax.get_ylabel() == 'prestrain (dimensionless)'
    assert figs[0].axes[1].get_ylabel() == 'pulse.speed_m_s (m/s)'      # the colour bar


def test_lens_title_gives_the_offsets_in_spacings_and_metres():
    result = {'focus_m': (0.08, 0.06), 'focal_gain': 1.42, 'dims': 2, 'medium_speed_m_s': 1.0,
              'peak_offset_spacings': 0.1, 'lateral_offset_spacings': 0.01}
    title = plots.lens_title(result, 0.03)
    assert title.endswith('across the focal depth 0.01 spacings (0.0003 m)'), title
    assert 'focal gain 1.42\nfield peak 0.10 column spacings (0.003 m) from the focus' in title
