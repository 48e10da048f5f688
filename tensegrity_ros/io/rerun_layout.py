"""The layout of a Rerun recording (docs/rerun.md): the blueprint a recording carries and the
text of its colour legend. :mod:`tensegrity_ros.io.rerun_sink` records into it."""
from __future__ import annotations

import rerun as rr
import rerun.blueprint as rrb
import rerun.blueprint.encodings as rrbe

TIMELINE = 'sim_time'
COLORMAP = 'Spectral'


def legend_markdown(tension_scale):
    """The text of the ``legend`` entity: what the colours of the 3D view mean."""
    return (f'**Cables**: tension T from blue (0 N) to red (T >= {tension_scale:.3g} N, twice '
            f'the largest prestress tension); slack cables grey and translucent. '
            f'**Bars** light grey, **nodes** orange. Heat map and bar charts: axial strain '
            f'(h - h0) / h, negative in compression; the heat map and the right bar chart on a '
            f'symmetric-log scale, sign(s) log10(1 + |s| / 0.01), so that a pulse of 0.1 shows '
            f'beside a crushed prism at -30.')


def blueprint(n_columns=1, field_grid=None, y_ranges=None):
    """The default layout, as the paper's figures: on the left the 3D column above the colour
    legend and the command log (with a ``field_grid``, the field in the medium under the 3D
    view); on the right the strain per prism at the time cursor, the prism-by-``sim_time`` heat
    map (the clamped end at the bottom, as in the 3D view) and its scale, base force, energy,
    energy balance error and constraint error side by side. The heat map and a second bar chart
    show strain on a symmetric-log scale (:func:`~tensegrity_ros.io.rerun_columns.symlog`).
    Several columns: one tab per column
    for the bar chart and the heat map. ``y_ranges``: ``{time series origin: (lo, hi)}``, fixed
    y ranges (the recorder gives them for series that stay constant, which the viewer would
    draw on an axis of +-1 around them)."""
    y_ranges = y_ranges or {}

    def series(origin, name):
        lo_hi = y_ranges.get(origin)
        axis = None if lo_hi is None else rrb.archetypes.ScalarAxis(range=lo_hi)
        return rrb.TimeSeriesView(origin=origin, name=name, axis_y=axis)

    def one_or_tabs(views):
        return views[0] if len(views) == 1 else rrb.Tabs(*views)
    mapping = rrb.archetypes.TensorScalarMapping(colormap=COLORMAP)
    bars = [rrb.Horizontal(
        rrb.BarChartView(origin=f'strain_profile/column_{c}',
                         name=f'strain per prism at the time cursor, column {c} '
                              f'(prism 0: clamped end)',
                         plot_legend=rrb.archetypes.PlotLegend(visible=False)),
        rrb.BarChartView(origin=f'strain_profile_log/column_{c}',
                         name='the same, symmetric log: sign(s) log10(1 + |s| / 0.01)',
                         plot_legend=rrb.archetypes.PlotLegend(visible=False)),
        name=f'column {c}') for c in range(n_columns)]
    waves = [rrb.Vertical(
        rrb.TensorView(origin=f'wave/column_{c}',
                       name=f'strain (symmetric log), prism x sim_time from the impact to the '
                            f'time cursor, column {c}',
                       slice_selection=rrb.archetypes.TensorSliceSelection(
                           width=rr.TensorDimensionSelection(1),
                           height=rr.TensorDimensionSelection(0, invert=True)),
                       scalar_mapping=mapping, view_fit='fill'),
        rrb.TensorView(origin=f'wave_scale/column_{c}', name='colour scale: strain',
                       scalar_mapping=mapping, view_fit='fill'),
        row_shares=[5, 1], name=f'column {c}') for c in range(n_columns)]
    left = [rrb.Spatial3DView(origin='world', name='column, cables coloured by tension')]
    shares = [6]
    if field_grid is not None:
        x0, x1, z0, z1 = field_grid
        where = f'x {x0:.3g} to {x1:.3g} m across, depth {z0:.3g} to {z1:.3g} m down'
        left.append(rrb.Horizontal(
            rrb.Spatial2DView(origin='field/peak_pressure',
                              name=f'peak pressure in the medium so far, {where}'),
            rrb.Spatial2DView(origin='field/pressure',
                              name='pressure at the time cursor (grey: zero)')))
        shares = [4, 3]
    left.append(rrb.TextDocumentView(origin='legend', name='colours'))
    left.append(rrb.TextLogView(
        origin='commands', name='commands and events (latest at the time cursor)',
        columns=rrb.archetypes.TextLogColumns(text_log_columns=[
            rrbe.TextLogColumn('LogLevel'), rrbe.TextLogColumn('Body'),
            rrbe.TextLogColumn('EntityPath', visible=False)])))
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(*left, row_shares=shares + [1, 2]),
            rrb.Vertical(
                one_or_tabs(bars), one_or_tabs(waves),
                rrb.Horizontal(series('base_force', 'base force, N'),
                               series('energy', 'energy, J'),
                               series('energy_balance_error', 'energy balance error'),
                               series('constraint_error', 'constraint error')),
                row_shares=[3, 4, 2]),
            column_shares=[2, 3]),
        rrb.BlueprintPanel(state='collapsed'), rrb.SelectionPanel(state='collapsed'),
        rrb.TimePanel(timeline=TIMELINE, state='collapsed'))
