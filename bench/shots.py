"""Strong shots on the default columns: real-time factor, energy balance and the figures a run
measures, against a refined reference (docs/physics.md section 7.1, "Strong shots").

    python -m bench.shots [--quick] [--out bench/results]      # tensegrity bench --only shots

Each case is one shot of ``v0`` on ``fb_column`` or ``rb_column``, ``T_END`` s simulated, run
once at the scene's steps (each contact treatment of ``TREATMENTS``) and once refined (``dt / 4``,
``contact.resolution x 4``). A row gives the real-time factor of the stepping loop (one run, the
machine otherwise idle), the RK4 steps, the contacts met, the largest balance error, and the
change against the refined run of the front figures (front speed, amplitude and arrival: ahead
of the chaotic motion behind the front, docs/physics.md section 7.1) and of the base-force peak
(the first peak at the far base, ``base[0].peak_N``; ``max_N``, the largest over the run, is
reported too, but behind the front the response is chaotic). The train case is the 20 impacts of
``fb_train.yaml`` then a 2 m/s shot at 1 s, 5 s simulated, in the solver and through the node
(:func:`node_train_then_shot`). Writes ``shots.json``.

``--coarse`` runs instead what the front figures alone ask of the contact steps
(:func:`coarse`): each case at ``contact.resolution`` 40, 20, 10 and 5 with the energy ledger
5,000 times looser (``divergence.energy_error`` 0.5, which also loosens the refinement's check
of each step), with and without the refinement, against the same refined reference. Writes
``shots_coarse.json``.

``--census`` counts where a shot's steps go (:func:`census`): each case stepped one ``dt`` at a
time, each interval of ``dt`` classed by whether its force evaluations met a contact, the steps
of each class and their refinement levels, and at the end of each interval the pairs of bars in
contact, the model's nodes they hold and the prisms whose bases touch. Writes
``shots_census.json``."""
from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

from solver.build.scene import Scene
from solver.simulate.results import json_safe
from solver.simulate.runner import ImpactTrain, _at_rest, run, summary
from solver.simulate.simulation import SimulationDiverged

ROOT = Path(__file__).resolve().parents[1]
CASES = (('fb_column', 1.0), ('fb_column', 2.0), ('rb_column', 1.0), ('rb_column', 2.0))
T_END = 2.0
REFINE = 4                      # the reference: dt / REFINE, contact.resolution x REFINE
FRONT = ('front_speed_m_s', 'front_amplitude', 'front_arrival_s')
# the contact treatments compared: name -> overrides (the first: the scene as it is). The other
# two are the cheap candidates: contact steps T / 20 instead of T / 40 (the ledger's refinement
# still checks every step), and bars 32 times softer (E / 32: a compliant contact whose duration
# is 4 times the Hertz contact's, so its steps are 4 times longer)
TREATMENTS = {'default': (), 'resolution 20': ('contact.resolution=20',),
              'bar_E / 32': ('materials.bar_E=6.25e9',)}
COARSE = (40, 20, 10, 5)        # contact.resolution of the coarse study
LOOSE = 'divergence.energy_error=0.5'
TRAIN_SHOT = (1.0, 2.0)         # the shot after the train: at 1 s, 2 m/s
TRAIN_T_END = 5.0


def _scene(name):
    return Scene.load(ROOT / 'config' / 'scenes' / f'{name}.yaml')


def shot(name, v0, t_end, overrides=(), refine=1):
    """One shot: the summary's figures, or the stop's message."""
    scene = _scene(name)
    sets = [f'loading.impact.v0={v0!r}', f'run.t_end={t_end!r}', *overrides]
    if refine > 1:
        sets += [f'integrator.dt={scene.integrator.dt / refine!r}',
                 f'contact.resolution={scene.contact.resolution * refine!r}']
    scene, sim = _at_rest(scene, sets)
    return _record(scene, sim, ImpactTrain(scene.loading.impact, sim.dt), t_end)


def train_then_shot(t_end=TRAIN_T_END, overrides=()):
    """``fb_train.yaml``'s 20 impacts, then a shot of ``TRAIN_SHOT``, to ``t_end``."""
    scene, sim = _at_rest(_scene('fb_train'), [f'run.t_end={t_end!r}', *overrides])
    train = ImpactTrain(scene.loading.impact, sim.dt)
    train.impacts.append((int(round(TRAIN_SHOT[0] / sim.dt)), TRAIN_SHOT[1]))
    return _record(scene, sim, train, t_end)


def node_train_then_shot(t_end=TRAIN_T_END, domain_id=120 + os.getpid() % 10):
    """The train and the shot through the node, as a user commands them: one FB column
    (the node as :mod:`bench.node_array` runs it, in this process, ``real_time_factor`` 0, 200 Hz
    publishing), each impact published on ``~/cmd/impact`` once the simulation has reached its
    time, then stepped to ``t_end``. The real-time factor counts from the first impact."""
    from bench.node_array import Session
    impacts = [(float(t), float(v0)) for t, v0 in _scene('fb_train').loading.impact.train()]
    impacts.append(TRAIN_SHOT)
    with tempfile.TemporaryDirectory() as folder:
        s = Session(1, folder, domain_id)
        try:
            s.reset()
            s.set_ramp(0.0)
            node, sim = s.node, s.node.sim
            t0, f0, d0 = sim.t, node.counts['frames'], node.divergences
            w0 = None
            for t, v0 in impacts:
                if not s.spin_until(lambda: sim.t - t0 >= t - 1e-12, 600.0):
                    raise RuntimeError(f'shots: the node did not reach t = {t} s')
                s.command('impact', [v0], 'all')
                w0 = time.perf_counter() if w0 is None else w0
            tail = s.window(3600.0, until_t=t0 + t_end)
            wall = time.perf_counter() - w0
            return {'real_time_factor': (sim.t - t0 - impacts[0][0]) / wall, 'wall_s': wall,
                    'frames_per_s': (node.counts['frames'] - f0) / wall,
                    'after_shot': tail, 'divergences': node.divergences - d0,
                    'energy_balance_error': float(sim.energy_error())}
        finally:
            s.close()


def _record(scene, sim, train, t_end):
    t0 = time.perf_counter()
    try:
        rec = run(sim, t_end, scene.run.output_dt, train=train)
    except SimulationDiverged as exc:
        return {'stopped': str(exc), 'wall_s': time.perf_counter() - t0}
    s = json_safe(summary(scene, sim, rec).to_json())   # ``tensegrity run --json``'s
    base = s['base'][0] if s['base'] else {}
    pulse = s['pulse'] or {}
    return {'real_time_factor': s['real_time_factor'], 'wall_s': s['wall_time_s'],
            'steps': s['steps_taken'], 'contacts_met': s['contacts_met'],
            'balance_error': s['energy_balance_error'],
            **{k: pulse.get(k) for k in FRONT},
            'base_peak_N': base.get('peak_N'), 'base_max_N': base.get('max_N')}


def _change(a, b):
    """Relative change of ``a`` against the reference ``b`` (None where either is missing)."""
    if a is None or b is None or b == 0:
        return None
    return abs(a - b) / abs(b)


def main(out_dir='bench/results', quick=False, log=print, treatments=None):
    """Every case under every treatment, and the refined reference; returns the files
    written."""
    t_end = 0.5 if quick else T_END
    treatments = TREATMENTS if treatments is None else treatments
    rows, refs = [], []
    for name, v0 in CASES:
        ref = shot(name, v0, t_end, refine=REFINE)
        refs.append({'scene': name, 'v0': v0, **ref})
        log(f'{name} {v0} m/s, reference: {_line(ref)}')
        for label, sets in treatments.items():
            row = {'scene': name, 'v0': v0, 'treatment': label, **shot(name, v0, t_end, sets)}
            for k in (*FRONT, 'base_peak_N', 'base_max_N'):
                row[f'{k}_change'] = _change(row.get(k), ref.get(k))
            rows.append(row)
            log(f'{name} {v0} m/s, {label}: {_line(row)}')
    train = {label: train_then_shot(1.5 if quick else TRAIN_T_END, sets)
             for label, sets in treatments.items()}
    for label, r in train.items():
        log(f'fb_train + {TRAIN_SHOT[1]} m/s at {TRAIN_SHOT[0]} s, {label}: {_line(r)}')
    node = node_train_then_shot(1.5 if quick else TRAIN_T_END)
    log(f"the same through the node: real-time factor {node['real_time_factor']:.2f}, "
        f"{node['frames_per_s']:.0f} frames/s, balance {node['energy_balance_error']:.1e}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / ('shots_quick.json' if quick else 'shots.json')
    path.write_text(json.dumps({'t_end_s': t_end, 'refine': REFINE, 'rows': rows,
                                'references': refs, 'train_then_shot': train,
                                'node_train_then_shot': node}, indent=1))
    return [str(path)]


def coarse(out_dir='bench/results', log=print, t_end=T_END):
    """The coarse study (module text): per case, resolution and refinement, the real-time
    factor, steps, balance error and the change of the front figures against the reference."""
    rows = []
    for name, v0 in CASES:
        ref = shot(name, v0, t_end, refine=REFINE)
        for res in COARSE:
            for refine in ('ledger', 'none'):
                sets = (f'contact.resolution={res}', f'contact.refine={refine}', LOOSE)
                row = {'scene': name, 'v0': v0, 'resolution': res, 'refine': refine,
                       **shot(name, v0, t_end, sets)}
                for k in (*FRONT, 'base_peak_N'):
                    row[f'{k}_change'] = _change(row.get(k), ref.get(k))
                rows.append(row)
                log(f'{name} {v0} m/s, T/{res}, refine {refine}: {_line(row)}')
    path = Path(out_dir) / 'shots_coarse.json'
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({'t_end_s': t_end, 'refine': REFINE, 'loose': LOOSE,
                                'rows': rows}, indent=1))
    return [str(path)]


def census(out_dir='bench/results', log=print, t_end=T_END):
    """The census of each case (module text): per class of interval (a contact met; several
    steps, none met; one plain step) the intervals and the RK4 steps; the steps by the contact
    step's refinement level at the interval's end; and the touching pairs, their nodes and the
    touching bases at the end of each interval (mean and largest)."""
    import numpy as np

    from solver.kernels import barcontact as bcm
    from solver.kernels.records import CONTACT_LEVEL, MET
    rows = []
    for name, v0 in CASES:
        scene, sim = _at_rest(_scene(name), [f'loading.impact.v0={v0!r}'])
        sim.apply_impact(v0)
        m, d = sim.model, sim.model.data
        bc = m.rec.bar_contact
        ends = np.asarray(bc.pairs)[:, [bcm.A_LO, bcm.A_HI, bcm.B_LO, bcm.B_HI]]
        classes = {k: [0, 0] for k in ('contact met', 'several steps, none met', 'one step')}
        by_level, pairs, nodes, bases = {}, [], [], []
        while sim.t < t_end - 1e-9:
            met, taken = d.contact.scan[MET], sim.steps_taken
            sim.advance(sim.dt)
            steps = sim.steps_taken - taken
            key = ('contact met' if d.contact.scan[MET] > met
                   else 'one step' if steps == 1 else 'several steps, none met')
            classes[key][0] += 1
            classes[key][1] += steps
            level = int(d.refine[CONTACT_LEVEL])
            by_level[level] = by_level.get(level, 0) + steps
            touching = [i for i in range(ends.shape[0]) if bcm._pair_energy(d.x, bc, i) > 0.0]
            pairs.append(len(touching))
            nodes.append(len(set(ends[touching].ravel().tolist())))
            bases.append(int(np.sum(sim._summary().heights < bc.diameter)))
        total = sum(n for _, n in classes.values())
        row = {'scene': name, 'v0': v0, 'model': m.name, 'model_nodes': int(d.x.shape[0]),
               'steps': total, 'intervals': {k: v[0] for k, v in classes.items()},
               'interval_steps': {k: v[1] for k, v in classes.items()},
               'steps_by_contact_level': {str(k): v for k, v in sorted(by_level.items())},
               'touching_pairs_mean': float(np.mean(pairs)), 'touching_pairs_max': max(pairs),
               'intervals_touching': float(np.mean(np.array(pairs) > 0)),
               'nodes_in_contact_mean': float(np.mean(nodes)),
               'nodes_in_contact_max': max(nodes),
               'touching_bases_mean': float(np.mean(bases)), 'touching_bases_max': max(bases)}
        rows.append(row)
        met = row['interval_steps']['contact met']
        log(f"{name} {v0} m/s: {total} steps, {met / total:.1%} in the "
            f"{row['intervals']['contact met']} intervals that met a contact; at an interval's "
            f"end {row['touching_pairs_mean']:.2f} pairs touch (at most "
            f"{row['touching_pairs_max']}), holding {row['nodes_in_contact_mean']:.1f} of "
            f"{row['model_nodes']} nodes (at most {row['nodes_in_contact_max']})")
    path = Path(out_dir) / 'shots_census.json'
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({'t_end_s': t_end, 'rows': rows}, indent=1))
    return [str(path)]


def _line(r):
    if 'stopped' in r:
        return f"stopped: {r['stopped']}"
    ch = ', '.join(f"{k} {r[k + '_change']:.2%}" for k in (*FRONT, 'base_peak_N')
                   if r.get(k + '_change') is not None)
    return (f"RTF {r['real_time_factor']:.2f}, {r['steps']} steps, balance "
            f"{r['balance_error']:.1e}" + (f'; against the reference: {ch}' if ch else ''))


if __name__ == '__main__':
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--quick', action='store_true')
    ap.add_argument('--out', default='bench/results')
    ap.add_argument('--coarse', action='store_true',
                    help='what the front figures alone ask of the contact steps (about 5 min)')
    ap.add_argument('--census', action='store_true',
                    help='where the steps of each shot go (about 1 min)')
    a = ap.parse_args()
    if a.coarse:
        coarse(a.out, t_end=0.5 if a.quick else T_END)
    elif a.census:
        census(a.out, t_end=0.5 if a.quick else T_END)
    else:
        main(a.out, quick=a.quick)
