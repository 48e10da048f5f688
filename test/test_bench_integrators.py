"""The bookkeeping of the integrator benchmarks (bench/work_precision.py, bench/stability.py) on
hand-made data: classification, fastest method per accuracy level, largest stable dt, and one tiny
real run through the recorder."""
import numpy as np

from bench import common, stability, work_precision


def _hist(strain, energy=None, cerr=None, diverged=None, quantity=None):
    n = len(strain)
    return common.History(times=np.arange(n) * 0.01, strain=np.asarray(strain, dtype=float),
                          energy=np.ones(n) if energy is None else np.asarray(energy, float),
                          constraint_error=np.zeros(n) if cerr is None else np.asarray(cerr),
                          wall_s=1.0, steps=n, diverged=diverged, quantity=quantity)


def test_strain_error_is_relative_to_the_peak():
    ref = _hist([[0.0, 0.0], [-0.1, 0.0], [0.0, -0.05]])
    run = _hist([[0.0, 0.0], [-0.1, 0.002], [0.0, -0.05]])
    assert np.isclose(common.strain_error(run, ref), 0.02)
    assert np.isnan(common.strain_error(_hist([[0.0, 0.0]]), ref))     # stopped early


def test_classification_of_cells():
    ref = _hist([[0.0], [-0.1], [-0.05]])
    close = _hist([[0.0], [-0.10005], [-0.05]])
    far = _hist([[0.0], [-0.09], [-0.05]])
    assert stability.classify(close, ref)[0] == 'accurate'
    assert stability.classify(far, ref)[0] == 'inaccurate'
    assert stability.classify(_hist([[0.0], [-0.1], [-0.05]], energy=[1.0, 1.0, 1.01]),
                              ref)[0] == 'drifting'
    assert stability.classify(_hist([[0.0], [-0.1], [-0.05]], cerr=[0, 0, 1e-5]),
                              ref)[0] == 'drifting'
    assert stability.classify(_hist([[0.0]], diverged='x', quantity='energy'),
                              ref)[0] == 'diverged'
    failed_ref = _hist([[0.0]], diverged='x', quantity='prism height')
    assert stability.classify(close, failed_ref)[0] == 'inaccurate'


def test_largest_stable_dt_stops_at_the_first_failure():
    rows = []
    for dt, cls in ((1e-3, 'accurate'), (2e-3, 'drifting'), (4e-3, 'diverged'),
                    (8e-3, 'drifting')):           # stable again above a failure: not counted
        for v0 in (0.1, 0.15):
            rows.append({'column': 'FB', 'method': 'm', 'prestrain': 0.002, 'v0': v0, 'dt': dt,
                         'class': cls})
    assert stability.largest_stable(rows, 'FB') == {'m': (2e-3, 1e-3)}


def test_fastest_method_per_accuracy_level():
    def row(method, err, wall):
        return {'column': 'FB', 'model': 'sym3d', 'method': method, 'dt': 1e-3, 'rtol': '',
                'strain_error_rel': err, 'wall_s': wall, 'wall_per_sim_s': wall / 0.4,
                'cost_vs_default': wall, 'status': 'ok'}
    rows = [row('a', 1e-3, 1.0), row('a', 1e-7, 4.0), row('b', 1e-5, 2.0), row('b', 1e-9, 3.0),
            dict(row('c', 1e-12, 0.1), status='diverged: energy')]
    best = {b['level']: (b['method'], b['runner_up']) for b in
            work_precision.fastest(rows, levels=(1e-2, 1e-4, 1e-6, 1e-8, 1e-10))}
    assert best == {1e-2: ('a', 'b'), 1e-4: ('b', 'a'), 1e-6: ('b', 'a'), 1e-8: ('b', ''),
                    1e-10: ('none', '')}


def test_record_of_a_short_run_is_finite_and_timed():
    sc = common.scene('FB', common.available_models()[0], 'rk4_projected', 1e-3, 4e-3, 0.02)
    h = common.record(sc)
    assert h.diverged is None and h.strain.shape == (6, 50) and h.wall_s > 0
    assert np.all(np.isfinite(h.strain)) and np.min(h.strain) < 0     # the impact compresses


def test_stiff_limits_give_the_stable_step_ratio_to_rk4_projected():
    rows = [{'scene': 's', 'method': m, 'dt': dt, 'class': c} for m, dt, c in (
        ('rk4_projected', 1e-4, 'drifting'), ('rk4_projected', 2e-4, 'diverged'),
        ('implicit_midpoint', 1e-4, 'accurate'), ('implicit_midpoint', 2e-4, 'inaccurate'),
        ('implicit_midpoint', 4e-4, 'diverged'))]
    lim = {r['method']: r for r in stability.stiff_limits(rows)}
    assert lim['rk4_projected']['largest_stable_dt'] == 1e-4
    assert lim['implicit_midpoint']['largest_stable_dt'] == 2e-4
    assert lim['implicit_midpoint']['largest_accurate_dt'] == 1e-4
    assert lim['implicit_midpoint']['stable_dt_vs_rk4_projected'] == 2.0


def test_stiff_limits_give_the_conserving_step_and_the_mean_step_taken():
    rows = [{'scene': 's', 'method': m, 'dt': dt, 'class': c, 'mean_step': step}
            for m, dt, c, step in (
                ('rk4_projected', 1e-4, 'inaccurate', 3e-5),
                ('rk4_projected', 2e-4, 'drifting', 3e-5),
                ('rk4_projected', 4e-4, 'diverged', float('nan')),
                ('implicit_midpoint', 1e-4, 'inaccurate', 1e-4),
                ('implicit_midpoint', 2e-4, 'inaccurate', 2e-4),
                ('implicit_midpoint', 4e-4, 'drifting', 4e-4))]
    lim = {r['method']: r for r in stability.stiff_limits(rows)}
    assert lim['rk4_projected']['largest_stable_dt'] == 2e-4
    assert lim['rk4_projected']['largest_conserving_dt'] == 1e-4
    assert lim['rk4_projected']['mean_step_at_stable_dt'] == 3e-5
    assert lim['implicit_midpoint']['largest_stable_dt'] == 4e-4
    assert lim['implicit_midpoint']['largest_conserving_dt'] == 2e-4
    assert lim['implicit_midpoint']['stable_dt_vs_rk4_projected'] == 2.0
    assert lim['implicit_midpoint']['conserving_dt_vs_rk4_projected'] == 2.0
    assert lim['implicit_midpoint']['largest_accurate_dt'] == ''


def test_largest_steps_separate_stable_conserving_and_accurate():
    rows = [{'column': 'RB', 'method': 'm', 'prestrain': 0.002, 'v0': 1.0, 'dt': dt, 'class': c}
            for dt, c in ((1e-4, 'accurate'), (2e-4, 'inaccurate'), (4e-4, 'drifting'),
                          (8e-4, 'diverged'), (1.6e-3, 'accurate'))]
    got = stability.largest_steps(rows, 'RB', v0s=(1.0,))['m']
    assert got == {'stable': 4e-4, 'conserving': 2e-4, 'accurate': 1e-4}
    drifting_first = [dict(rows[0], **{'class': 'drifting'})]
    assert stability.largest_steps(drifting_first, 'RB', v0s=(1.0,))['m'] == {
        'stable': 1e-4, 'conserving': None, 'accurate': None}


def test_contact_limits_put_both_maps_side_by_side():
    def cells(classes):
        return [{'column': 'RB', 'method': 'rk4_projected', 'prestrain': 0.002, 'v0': 0.5,
                 'dt': dt, 'class': c, 'reference': 'ok'} for dt, c in classes]
    plain = cells(((1e-3, 'diverged'), (2e-3, 'diverged')))
    stops = cells(((1e-3, 'inaccurate'), (2e-3, 'diverged')))
    out = stability.contact_limits({'none': plain, 'stops': stops})
    assert [(r['contact'], r['largest_stable_dt'], r['largest_conserving_dt']) for r in out] == [
        ('none', '', ''), ('stops', 1e-3, 1e-3)]


def test_implicit_midpoint_is_left_out_of_scenes_it_refuses():
    cables = ('structure.rigid_bases_as=stiff_cables', 'structure.kappa=1e4')
    assert 'implicit_midpoint' in stability.stiff_methods(cables)
    for extra in ('loading.impact.mode=striker', 'contact.lock=penalty',
                  'materials.cable_damping=0.1'):
        methods = stability.stiff_methods(cables + (extra,))
        assert 'implicit_midpoint' not in methods and 'rk4_projected' in methods
    assert 'implicit_midpoint' in stability.stiff_methods(cables + ('contact.lock=none',
                                                                    'materials.cable_damping=0'))
    striker = [o for n, (c, o) in stability.STIFF_SCENES.items() if 'striker' in n]
    assert striker and all('implicit_midpoint' not in stability.stiff_methods(o)
                           for o in striker)


def test_stiff_fastest_ranks_finished_runs_by_energy_drift_and_wall_time():
    def row(method, drift, wall, status='ok'):
        return {'scene': 's', 'method': method, 'dt': 1e-3, 'rtol': '', 'wall_s': wall,
                'wall_per_sim_s': wall / 0.128, 'energy_drift_rel': drift, 'status': status}
    rows = [row('explicit', 1e-3, 1.0), row('explicit', 1e-6, 8.0), row('implicit', 1e-5, 2.0),
            row('implicit', 1e-7, 4.0), row('broken', 1e-12, 0.1, 'diverged: energy')]
    best = {b['energy_level']: (b['method'], b['runner_up'], b['runner_up_ratio'])
            for b in work_precision.stiff_fastest(rows, levels=(1e-3, 1e-5, 1e-6, 1e-7, 1e-9))}
    assert best[1e-3] == ('explicit', 'implicit', 2.0)
    assert best[1e-5] == ('implicit', 'explicit', 4.0)     # explicit at 1e-6 is slower
    assert best[1e-6] == ('implicit', 'explicit', 2.0)
    assert best[1e-7][:2] == ('implicit', '') and np.isnan(best[1e-7][2])
    assert best[1e-9][0] == 'none'
