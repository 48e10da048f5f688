"""The paper's table under every modelling variant a scene supports (``tensegrity paper``).

Fabbrocino & Carpentieri (2017) report, for the 50-prism column with flexible bases (FB) at cross
prestrain 0.002, the leading-pulse amplitude and speed at v0 = 0.100, 0.125, 0.150 m/s
(docs/physics.md section 5). Their modelling choices are partly unstated; this module runs every
variant the scenes can express, each from a stated model and nothing else:

- bases: FB (ordinary base cables) or RB (rigid bases), RB as rigid edges or as stiff cables
  (``kappa`` x EA);
- stacking: shared base cables (interior ones carry two prisms' self-stress) or two parallel cables
  per interior side (one per prism);
- impact initial condition: ``impulse`` (velocity jump projected on the constraints) or ``energy``
  (projected, then rescaled to ``3 m v0^2 / 2``);
- model: ``sym3d`` (exact, equal to ``full3d`` on these symmetric scenes) and ``chain1d`` (the
  quasi-static 1D chain, an approximation whose error against the 3D model is measured here).

Also measured in the same run: the ``full3d`` / ``sym3d`` wall-time ratio (side by side, same
process) and their agreement. Pure solver code: no ROS, no printing (the CLI formats).
"""
from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from solver.analysis import observables
from solver.simulate.runner import run
from solver.build.scene import Scene
from solver.simulate.simulation import SimulationDiverged
from solver.simulate.array import simulation_for

SCENES = Path(__file__).resolve().parents[2] / 'config' / 'scenes'   # a checkout's; an install's:
# the caller passes ``scenes`` (tensegrity_ros finds its data files)
V0S = (0.100, 0.125, 0.150)
PAPER_FB = {0.100: {'amplitude': 0.054, 'speed_m_s': 0.248},
            0.125: {'amplitude': 0.0697, 'speed_m_s': None},
            0.150: {'amplitude': 0.085, 'speed_m_s': 0.372}}
# A speed is that of a travelling pulse only when the slope of the leading peak's position
# against time is positive and fitted over at least MIN_SPEED_POINTS output frames inside the
# window (prisms 10-40 from the impact); otherwise the table marks it (speed_note).
MIN_SPEED_POINTS = 5
SPEED_NOTES = {
    'no pulse': 'the leading peak never reached prism 10 from the impacted end',
    'few points': f'fitted over fewer than {MIN_SPEED_POINTS} frames in the window',
    'negative': 'the peak moved back towards the impacted end (slope <= 0)'}
DEFAULT_VARIANT = {'stacking': 'shared', 'impact': 'impulse', 'rigid_bases_as': 'edges'}


@dataclass
class Variant:
    """One modelling variant of one column (``bases`` 'flexible' or 'rigid')."""
    bases: str
    stacking: str
    rigid_bases_as: str
    impact: str
    model: str
    scene: str = ''     # a scene file of its own (the identified model): only v0 and t_end set

    @property
    def column(self):
        return 'FB' if self.bases == 'flexible' else 'RB'

    def label(self):
        if self.scene:
            return f'{self.column} identified ({Path(self.scene).name}) {self.model}'
        parts = [self.column, self.stacking if self.uses_stacking else '-']
        if self.bases == 'rigid':
            parts.append(self.rigid_bases_as)
        parts += [self.impact, self.model]
        return ' '.join(parts)

    @property
    def uses_stacking(self):
        return not (self.bases == 'rigid' and self.rigid_bases_as == 'edges')

    def overrides(self, v0, t_end):
        if self.scene:
            return [f'loading.impact.v0={v0}', f'model={self.model}', f'run.t_end={t_end}']
        sets = [f'structure.bases={self.bases}', f'structure.stacking={self.stacking}',
                f'structure.rigid_bases_as={self.rigid_bases_as}',
                f'loading.impact.mode={self.impact}', f'loading.impact.v0={v0}',
                f'model={self.model}', f'run.t_end={t_end}']
        if self.bases == 'rigid' and self.rigid_bases_as == 'stiff_cables':
            sets.append('integrator.dt=1e-4')   # stiff base cables: keep the step well resolved
        return sets


@dataclass
class Row:
    """Figures of one run (docs/physics.md section 4); ``status`` 'ok' or why the run stopped."""
    variant: dict
    label: str
    v0: float
    amplitude: float = math.nan
    amplitude_median: float = math.nan
    speed_m_s: float = math.nan
    width_prisms: int = 0
    arrival_time_s: float = math.nan
    ke_fraction: float = math.nan
    speed_points: int = 0
    speed_note: str = ''
    wall_time_s: float = 0.0
    status: str = 'ok'
    paper: dict = field(default_factory=dict)
    chain_error: dict = field(default_factory=dict)


def variants(models=('sym3d', 'chain1d'), scenes=SCENES):
    """Every variant the FB and RB scenes support; chain1d once per structure (its impact has no
    constraint to project, so the impulse and energy modes coincide)."""
    out = []
    structures = [('flexible', 'shared', 'edges'), ('flexible', 'parallel', 'edges'),
                  ('rigid', 'shared', 'edges'), ('rigid', 'shared', 'stiff_cables'),
                  ('rigid', 'parallel', 'stiff_cables')]
    for bases, stacking, rb_as in structures:
        for model in models:
            impacts = ('impulse',) if model == 'chain1d' else ('impulse', 'energy')
            for impact in impacts:
                out.append(Variant(bases, stacking, rb_as, impact, model))
    for name, bases in (('paper_fb.yaml', 'flexible'), ('paper_rb.yaml', 'rigid')):
        path = Path(scenes) / name  # the model identified on the FB figures (docs/paper.md)
        if path.exists():
            sc = Scene.load(path)
            out.append(Variant(bases, sc['structure.stacking'], sc['structure.rigid_bases_as'],
                               sc['loading.impact.mode'], 'auto', scene=str(path)))
    return out


def run_variant(variant, v0, t_end=1.2, output_dt=0.005, sets=(), scenes=SCENES):
    """One :class:`Row`: the variant's scene (or the column scene of its bases in ``scenes``),
    impact v0, run to ``t_end``."""
    path = variant.scene or Path(scenes) / ('fb_column.yaml' if variant.bases == 'flexible'
                                            else 'rb_column.yaml')
    # ``sets``: modelling options applied to every variant (``tensegrity paper --set``), the
    # identified scenes excepted (they are a fixed choice of those options)
    extra = [] if variant.scene else list(sets)
    scene = Scene.load(path).with_overrides(variant.overrides(v0, t_end) + extra)
    row = Row(variant=asdict(variant), label=variant.label(), v0=v0)
    if variant.bases == 'flexible':
        row.paper = dict(PAPER_FB[v0])
    sim = simulation_for(scene)
    sim.advance(sim.dt)          # compile (or load) kernels outside the timing
    sim.reset()
    m_node = float(np.mean(sim.network.node_mass))
    added = sim.apply_impact(v0)
    row.ke_fraction = added / (1.5 * m_node * v0 ** 2)
    t0 = time.perf_counter()
    try:
        rec = run(sim, t_end, output_dt)
    except SimulationDiverged as exc:
        row.status = str(exc)
        row.wall_time_s = time.perf_counter() - t0
        return row
    row.wall_time_s = rec.wall_time_s
    p = observables.first_passage(rec.times, rec.strain[:, 0], sim.network.h0)
    row.amplitude, row.amplitude_median = p.amplitude, p.amplitude_median
    row.speed_m_s, row.width_prisms, row.arrival_time_s = p.speed_m_s, p.width_prisms, \
        p.arrival_time_s
    row.speed_points = speed_points(rec.strain[:, 0])
    row.speed_note = speed_note(row.speed_m_s, row.speed_points)
    return row


def speed_points(strain, window=(10, 40)):
    """The number of frames the speed of :func:`observables.first_passage` is fitted over: frames
    up to the leading peak's first arrival near the clamped end whose peak lies in ``window``
    (prisms from the impact). ``strain`` (n_t, n_prisms) of one column."""
    n = strain.shape[1]
    count = 0
    for eps in strain:
        pos, _ = observables.leading_peak(eps[::-1])
        if math.isfinite(pos) and window[0] <= pos <= window[1]:
            count += 1
        if math.isfinite(pos) and pos >= n - 2:
            break
    return count


def speed_note(speed_m_s, n_points):
    """'' for the speed of a travelling pulse, else the key of :data:`SPEED_NOTES` saying why the
    figure is not one: no fit, a fit over fewer than :data:`MIN_SPEED_POINTS` frames, or a slope
    that is not positive."""
    if not math.isfinite(speed_m_s):
        return 'no pulse'
    if n_points < MIN_SPEED_POINTS:
        return 'few points'
    if speed_m_s <= 0:
        return 'negative'
    return ''


def chain_errors(rows):
    """Attach to each chain1d row its error against the sym3d row of the same structure, impulse
    impact and v0: amplitude and speed ratios, arrival-time difference (s)."""
    ref = {}
    for r in rows:
        v = r.variant
        if v['model'] == 'sym3d' and v['impact'] == 'impulse':
            ref[(v['bases'], v['stacking'], v['rigid_bases_as'], r.v0)] = r
    for r in rows:
        v = r.variant
        if v['model'] != 'chain1d':
            continue
        s = ref.get((v['bases'], v['stacking'], v['rigid_bases_as'], r.v0))
        if s is None:
            continue

        def ratio(a, b):
            return a / b if (math.isfinite(a) and math.isfinite(b) and b != 0) else math.nan
        r.chain_error = {
            'amplitude_ratio': ratio(r.amplitude_median, s.amplitude_median),
            'speed_ratio': ratio(r.speed_m_s, s.speed_m_s),
            'arrival_time_diff_s': (r.arrival_time_s - s.arrival_time_s
                                    if math.isfinite(r.arrival_time_s)
                                    and math.isfinite(s.arrival_time_s) else math.nan),
            'reference': s.label}
    return rows


def speed_ratio(v0=0.1, t_end=1.2, repeats=3, scenes=SCENES):
    """Wall time of ``full3d`` over ``sym3d`` on the FB and RB columns (rk4_projected, default
    dt), measured alternately in this process (best of ``repeats``), and the largest relative
    difference of their node positions at ``t_end``."""
    out = {}
    for name in ('fb_column', 'rb_column'):
        scene = Scene.load(Path(scenes) / f'{name}.yaml').with_overrides([f'run.t_end={t_end}'])
        best, pos = {}, {}
        for _ in range(repeats):
            for model in ('full3d', 'sym3d'):
                sim = simulation_for(scene.with_overrides([f'model={model}']))
                sim.advance(sim.dt)
                sim.reset()
                sim.apply_impact(v0)
                t0 = time.perf_counter()
                sim.advance(t_end)
                best[model] = min(best.get(model, math.inf), time.perf_counter() - t0)
                pos[model] = sim.model.positions()
        diff = float(np.max(np.abs(pos['full3d'] - pos['sym3d'])) / np.max(np.abs(pos['full3d'])))
        out[name] = {'full3d_s': best['full3d'], 'sym3d_s': best['sym3d'],
                     'ratio': best['full3d'] / best['sym3d'], 'max_rel_diff': diff,
                     't_end': t_end, 'v0': v0}
    return out


def paper_table(v0s=V0S, t_end=1.2, models=('sym3d', 'chain1d'), progress=None, quick=False,
                sets=(), scenes=SCENES):
    """Every variant at every v0: ``{'rows': [Row...], 'speed': {...}, 'paper_fb': ...}``.
    ``progress(n)`` is called after each run. ``t_end`` (s) covers the pulse window (prisms 10-40
    from the impact) and the reference time 0.5 s. ``scenes``: the folder of the shipped scenes
    (``fb_column.yaml``, ``rb_column.yaml``, ``paper_fb.yaml``, ``paper_rb.yaml``)."""
    rows = []
    for variant in variants(models, scenes):
        for v0 in v0s:
            if sets and variant.model == 'chain1d':
                continue                # the chain has none of the 3D options
            rows.append(run_variant(variant, v0, t_end=t_end, sets=sets, scenes=scenes))
            if progress is not None:
                progress(1)
    chain_errors(rows)
    speed = speed_ratio(t_end=0.2 if quick else t_end, scenes=scenes)
    if progress is not None:
        progress(1)
    return {'rows': rows, 'speed': speed, 'paper_fb': PAPER_FB, 'default': DEFAULT_VARIANT,
            't_end': t_end, 'sets': [str(x) for x in sets]}


def n_runs(v0s=V0S, models=('sym3d', 'chain1d'), scenes=SCENES):
    """Number of progress ticks of :func:`paper_table`."""
    return len(variants(models, scenes)) * len(v0s) + 1


def as_json(result):
    """A JSON-ready dict (NaN -> None)."""
    def clean(x):
        if isinstance(x, float):
            return x if math.isfinite(x) else None
        if isinstance(x, dict):
            return {str(k): clean(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [clean(v) for v in x]
        return x
    out = dict(result)
    out['rows'] = [asdict(r) for r in result['rows']]
    return clean(out)


def _f(x, fmt):
    return format(x, fmt) if isinstance(x, (int, float)) and math.isfinite(x) else '-'


def legend():
    """One line per column of :func:`format_table` (and one per speed mark)."""
    return [
        "variant: bases (FB flexible, RB rigid); stacking of the interior base cables (shared "
        "or parallel; '-' for RB as rigid edges, which have no base cables); for RB, how the "
        "rigid bases are modelled (edges: rigid members; stiff_cables: cables of kappa x EA); "
        "the impact initial condition (impulse or energy); the model (sym3d, chain1d)",
        'v0: impact velocity, m/s',
        'KE kept: kinetic energy just after the impact over 3 m v0^2 / 2 (the three nodes of '
        'the impacted level at v0); below 1, the constraint projection removed the rest',
        'amp@0.5s: |strain| of the leading compressive peak at t = 0.5 s '
        "('-': it had reached the clamped end by then)",
        'amp median: median |strain| of the leading peak while it is in prisms 10-40 from the '
        'impacted end',
        'speed m/s: slope of the peak position against time there, times the prism height; '
        'marked instead of printed when it is not a travelling pulse: '
        + '; '.join(f'({k}) {v}' for k, v in SPEED_NOTES.items()),
        'width: prisms around the peak at >= half its strain at t = 0.5 s',
        'arrival s: first time the peak is in the window (prism 10 from the impact)',
        "paper amp, paper speed: Fabbrocino & Carpentieri's FB figures ('-': not reported)",
        'chain/3D amp, chain/3D speed: chain1d over the sym3d impulse row of the same '
        'structure and v0 (amp median, speed)',
        'chain-3D arrival s: chain1d arrival time minus that of the same sym3d row, s']


def format_table(result, markdown=False):
    """The table as text (``markdown=True``: a Markdown table for the README)."""
    head = ['variant', 'v0', 'KE kept', 'amp@0.5s', 'amp median', 'speed m/s', 'width',
            'arrival s', 'paper amp', 'paper speed', 'chain/3D amp', 'chain/3D speed',
            'chain-3D arrival s']
    lines = []
    for r in result['rows']:
        ce = r.chain_error or {}
        paper = r.paper or {}
        if r.status != 'ok':
            why = r.status.split(': ', 1)[-1].split(';')[0]
            t = r.status.split('t = ')[1].split(' s')[0] if 't = ' in r.status else '?'
            figures = [f'stopped at t = {t} s: {why}'] + [''] * 4
        else:
            note = r.speed_note
            speed = f'({note})' if note else _f(r.speed_m_s, '.3f')
            figures = [_f(r.amplitude, '.4f'), _f(r.amplitude_median, '.4f'), speed,
                       str(r.width_prisms), _f(r.arrival_time_s, '.3f')]
        lines.append([r.label, f'{r.v0:.3f}', _f(r.ke_fraction, '.3f')] + figures + [
            _f(paper.get('amplitude'), '.4f'), _f(paper.get('speed_m_s'), '.3f'),
            _f(ce.get('amplitude_ratio'), '.2f'), _f(ce.get('speed_ratio'), '.2f'),
            _f(ce.get('arrival_time_diff_s'), '+.3f')])
    out = []
    if result.get('sets'):
        out += ['options applied to every variant but the identified ones: '
                + ', '.join(result['sets']), '']
    if markdown:
        out.append('| ' + ' | '.join(head) + ' |')
        out.append('|' + '---|' * len(head))
        for line in lines:
            out.append('| ' + ' | '.join(line) + ' |')
    else:
        widths = [max(len(h), *(len(line[i]) for line in lines if not line[3].startswith('stop')
                                or i < 3))
                  for i, h in enumerate(head)]
        out.append('  '.join(h.ljust(w) for h, w in zip(head, widths)))
        for line in lines:
            if line[3].startswith('stopped'):
                out.append('  '.join(c.ljust(w) for c, w in zip(line[:3], widths)) + '  '
                           + line[3])
            else:
                out.append('  '.join(c.ljust(w) for c, w in zip(line, widths)))
    out.append('')
    bullet = '- ' if markdown else ''
    out += [bullet + line for line in legend()]
    out.append('')
    if result['speed']:
        out.append('Wall time of sym3d against full3d (one run each):')
    for name, s in result['speed'].items():
        bullet = '- ' if markdown else ''
        out.append(f"{bullet}{name}: full3d {s['full3d_s']:.3f} s, sym3d {s['sym3d_s']:.3f} s "
                   f"wall for {s['t_end']:g} s simulated (v0 = {s['v0']:g} m/s): full3d / sym3d = "
                   f"{s['ratio']:.2f}, largest relative position difference "
                   f"{s['max_rel_diff']:.1e}")
    return '\n'.join(out)
