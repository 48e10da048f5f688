"""The README's table of current figures, made from the result files of the commands it names.

    python -m tools.figures            # print each row's value as the result files give it
    python -m tools.figures --check    # exit 1 naming every figure that differs from its file
    python -m tools.figures --write    # rewrite the value column of README.md from the files

Each row of :data:`ROWS` names the figure (the start of the README row's first cell), the text of
its value cell with ``{}`` for each number, and where each number comes from: a result file under
``bench/results/`` (JSON key path or CSV row) and its format. :data:`DOC_FIGURES` does the same for
figures quoted in docs/, and docs/models.md's table of ``tensegrity paper --markdown`` is compared
with ``bench/results/paper.json``, docs/physics.md's convergence table with
``bench/results/trains.json``. ``test/test_docs.py`` runs the checks.
"""
from __future__ import annotations

import csv
import json
import re
import sys
from functools import lru_cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / 'bench' / 'results'
README = ROOT / 'README.md'


@lru_cache(maxsize=None)
def _json(name):
    return json.loads((RESULTS / name).read_text(encoding='utf-8'))


@lru_cache(maxsize=None)
def _csv(name):
    with open(RESULTS / name, newline='', encoding='utf-8') as f:
        return list(csv.DictReader(f))


def fmt(value, spec):
    """``format(value, spec)``; ``e1``: one decimal in scientific notation with a short exponent
    (8.6e-4)."""
    if spec == 'e1':
        from bench.common import short_e
        return short_e(value)
    return format(value, spec)


def J(name, *path, spec='.3g', scale=1.0):
    """A number of a JSON result file: keys (or list indices) in turn."""
    def get():
        node = _json(name)
        for key in path:
            node = node[key]
        return fmt(node * scale, spec)
    get.source = f'{name}: {".".join(str(p) for p in path)}'
    return get


def C(name, field, spec='.3g', scale=1.0, **where):
    """A number of a CSV result file: column ``field`` of the one row matching ``where``."""
    def get():
        rows = [r for r in _csv(name) if all(r[k] == v for k, v in where.items())]
        if len(rows) != 1:
            raise LookupError(f'{name}: {len(rows)} rows match {where}')
        value = rows[0][field]
        return value if spec == 'str' else fmt(float(value) * scale, spec)
    get.source = f'{name}: {field} where {where}'
    return get


def F(source, func):
    """A number computed from result files by ``func()`` (already formatted)."""
    func.source = source
    return func


def _trains_max(period):
    rows = [r for r in _json('trains.json')['rows'] if r['period_s'] == period]
    return fmt(max(r['balance_error_max'] for r in rows), 'e1')


def _impacts(key):
    """Over both columns of bench/results/impacts.json with the refined steps: the points
    stopped (``stopped``) or the largest balance error (``balance_error_max``)."""
    s = [v['ledger'] for v in _json('impacts.json')['summary'].values()]
    if key == 'stopped':
        return str(sum(m['stopped'] for m in s))
    return fmt(max(m['balance_error_max'] for m in s), 'e1')


def _front(scene, key):
    """The single impact of 1 m/s on ``scene`` in bench/results/trains.json's refinement
    ladder: its front speed at the scene's steps (``speed``) or that speed's relative change at
    the first halving (``change``)."""
    c = next(c for c in _json('trains.json')['convergence']
             if c['scene'] == scene and c['v0'] == 1.0)
    if key == 'speed':
        return fmt(c['ladder'][0]['figures']['front_speed_m_s'], '.3f')
    return fmt(c['steps'][0]['front_speed_m_s'], 'e1')


def _trains_lost():
    rows = _json('trains.json')['rows']
    return 'no prism lost' if all(r['status'] == 'ok' for r in rows) else 'prisms lost'


def _peer_ratio(peer):
    d = _json('peers.json')
    return fmt(d[peer]['cpu_s'] / d['ours']['cpu_s'], '.0f')


def _contact_limit():
    rows = [r for r in _csv('stability_contact_limits.csv')
            if r['method'] == 'rk4_projected' and r['contact'] != 'none']
    return fmt(min(float(r['largest_stable_dt']) for r in rows) * 1e3, '.0f')


def _node_rounds(which):
    rows = _json('node_overhead_sym3d.json')['rows']
    values = [100 * (1 - r['ratio_rtf0_bare']) for r in rows]
    return fmt(min(values) if which == 'min' else max(values), '.0f')


def _soak_non_finite():
    d = _json('actuator.json')
    return str(d['strain_non_finite_received'] + d['nodes_non_finite_received'])


WP = dict(ranking='wall time', column='FB', model='sym3d', level='1e-06')
STIFF = dict(scene='RB, stiff-cable bases, kappa 1e4')
ROWS = [
    ('FB column, v0 0.1 m/s', '{}, {} m/s', [
        J('fb_column/summary.json', 'pulse', 'amplitude', spec='.3f'),
        J('fb_column/summary.json', 'pulse', 'speed_m_s', spec='.3f')]),
    ('closest model of the family', '{}, {} m/s; {}, {} m/s', [
        J('paper_id/predict.json', 'identified FB', '0.1', 'pulse.amplitude', spec='.3f'),
        J('paper_id/predict.json', 'identified FB', '0.1', 'pulse.speed_m_s', spec='.3f'),
        J('paper_id/predict.json', 'identified FB', '0.15', 'pulse.amplitude', spec='.3f'),
        J('paper_id/predict.json', 'identified FB', '0.15', 'pulse.speed_m_s', spec='.3f')]),
    ('ours at strain error', '{} in {} s CPU ({}x real time)', [
        J('peers.json', 'ours', 'strain_error', spec='e1'),
        J('peers.json', 'ours', 'cpu_s', spec='.3f'),
        J('peers.json', 'ours', 'real_time_factor', spec='.0f')]),
    ('speed-up against MuJoCo', '{}x, {}x', [
        F('peers.json: mujoco.cpu_s / ours.cpu_s', lambda: _peer_ratio('mujoco')),
        F('peers.json: scipy.cpu_s / ours.cpu_s', lambda: _peer_ratio('scipy'))]),
    ('a step through', '{}', [
        J('peers.json', 'kernel', 'step_over_kernel_bound', spec='.2f')]),
    ('fastest method at strain error 1e-6', '`{}`, dt {} ms: {} s', [
        C('work_precision_fastest.csv', 'method', spec='str', **WP),
        C('work_precision_fastest.csv', 'dt', spec='.1f', scale=1e3, **WP),
        C('work_precision_fastest.csv', 'wall_per_sim_s', spec='.3f', **WP)]),
    ('largest stable (accurate) dt', '{} ms FB, {} ms RB ({} ms); every cell runs to {} ms', [
        C('stability_limits.csv', 'largest_stable_dt', spec='.0f', scale=1e3, column='FB',
          method='rk4_projected'),
        C('stability_limits.csv', 'largest_stable_dt', spec='.0f', scale=1e3, column='RB',
          method='rk4_projected'),
        C('stability_limits.csv', 'largest_accurate_dt', spec='.0f', scale=1e3, column='FB',
          method='rk4_projected'),
        F('stability_contact_limits.csv: smallest largest_stable_dt of rk4_projected with bar '
          'contact', _contact_limit)]),
    ('200 impacts', '{}, {}; {}', [
        F('trains.json: largest balance_error_max of the 10 ms trains', lambda: _trains_max(0.01)),
        F('trains.json: largest balance_error_max of the 50 ms trains', lambda: _trains_max(0.05)),
        F('trains.json: every row ok', _trains_lost)]),
    ('70 single impacts', '{}, {}', [
        F('impacts.json: points stopped with contact.refine ledger', lambda: _impacts('stopped')),
        F('impacts.json: largest balance error with contact.refine ledger',
          lambda: _impacts('balance_error_max'))]),
    ('shot, 2 s: real-time factor', '{}, {}; {}, {}; {}', [
        J('shots.json', 'rows', 0, 'real_time_factor', spec='.2f'),     # FB 1 m/s, default
        J('shots.json', 'rows', 6, 'real_time_factor', spec='.2f'),     # RB 1 m/s
        J('shots.json', 'rows', 3, 'real_time_factor', spec='.2f'),     # FB 2 m/s
        J('shots.json', 'rows', 9, 'real_time_factor', spec='.2f'),     # RB 2 m/s
        J('shots.json', 'node_train_then_shot', 'real_time_factor', spec='.2f')]),
    ('1 m/s impact, FB, RB: front speed', '{}, {} m/s; {}, {}', [
        F('trains.json: front_speed_m_s at the scene steps, fb_column 1 m/s',
          lambda: _front('fb_column', 'speed')),
        F('trains.json: front_speed_m_s at the scene steps, rb_column 1 m/s',
          lambda: _front('rb_column', 'speed')),
        F('trains.json: its change at dt/2, fb_column', lambda: _front('fb_column', 'change')),
        F('trains.json: its change at dt/2, rb_column', lambda: _front('rb_column', 'change'))]),
    ('node, 30 s flood', '{}, {}, {}', [
        J('actuator.json', 'frames_per_s', spec='.1f'),
        F('actuator.json: non-finite strain and node messages received', _soak_non_finite),
        J('actuator.json', 'pauses', spec='.0f')]),
    ('stiff RB column', '{} vs {} ms', [
        C('stability_stiff_limits.csv', 'largest_stable_dt', spec='.2g', scale=1e3,
          method='implicit_midpoint', **STIFF),
        C('stability_stiff_limits.csv', 'largest_stable_dt', spec='.2g', scale=1e3,
          method='rk4_projected', **STIFF)]),
    ('node, 200 Hz', '+{} % ({}-{} %); {}x; {}x, {} Hz', [
        J('node_overhead_sym3d.json', 'overhead', spec='.1f', scale=100),
        F('node_overhead_sym3d.json: smallest overhead of a round', lambda: _node_rounds('min')),
        F('node_overhead_sym3d.json: largest overhead of a round', lambda: _node_rounds('max')),
        J('node_overhead_sym3d.json', 'node_rtf1_rtf', spec='.3f'),
        J('node_overhead_sym3d_record.json', 'node_rtf1_rtf', spec='.3f'),
        J('node_overhead_sym3d_record.json', 'node_rtf1_rate_hz', spec='.0f')]),
    ('Rerun recording', 'wall +{} % (+{} %), CPU +{} % (+{} %)', [
        J('rerun_overhead.json', 'wall_overhead_median', spec='.1f', scale=100),
        J('rerun_overhead_t4.8.json', 'wall_overhead_median', spec='.1f', scale=100),
        J('rerun_overhead.json', 'cpu_overhead_median', spec='.0f', scale=100),
        J('rerun_overhead_t4.8.json', 'cpu_overhead_median', spec='.0f', scale=100)]),
    ('256-point FB sweep', '{}x, {}x; {}x', [
        J('sweep.json', 'batched_1_ratio_per_point', spec='.2f'),
        J('sweep.json', 'batched_threads_ratio', spec='.2f'),
        J('sweep.json', 'cluster_ratio', spec='.2f')]),
    ('array, cost per column', '{}x (median {}x), {}x, {}x, {}x', [
        J('array.json', 'rows', 0, 'ratio_per_column', spec='.2f'),
        J('array.json', 'rows', 0, 'ratio_median', spec='.2f'),
        J('array.json', 'rows', 1, 'ratio_per_column', spec='.3f'),
        J('array.json', 'rows', 2, 'ratio_per_column', spec='.2f'),
        J('array.json', 'rows', 3, 'ratio_per_column', spec='.1f')]),
    ('lanes, 64 FB columns', '{}x, {}x; {} s ({} s); {}, {} (peak {})', [
        J('lanes.json', 'runs', 4, 'ratio', spec='.2f'),
        J('lanes.json', 'runs', 5, 'ratio', spec='.2f'),
        J('lanes.json', 'sweep_1024', 'lanes_s', spec='.1f'),
        J('lanes.json', 'sweep_1024', 'one_at_a_time_s', spec='.1f'),
        J('flops.json', 'rows', 0, 'gflops', spec='.1f'),
        J('flops.json', 'rows', 2, 'gflops', spec='.1f'),
        J('flops.json', 'peak', 'peak_gflops_256bit', spec='.0f')]),
]


def _paper_row(label, v0):
    rows = [r for r in _json('paper.json')['rows'] if r['label'] == label and r['v0'] == v0]
    if len(rows) != 1:
        raise LookupError(f'paper.json: {len(rows)} rows {label} at v0 = {v0}')
    return rows[0]


def P(label, v0, key, spec='.3f'):
    """A figure of a row of ``tensegrity paper --json`` (bench/results/paper.json)."""
    return F(f'paper.json: {key} of {label} at v0 = {v0}',
             lambda: fmt(_paper_row(label, v0)[key], spec))


def _identified(v0, key, target, spec):
    value = _json('paper_id/predict.json')['identified FB'][v0][key]
    return fmt(value, spec) if target is None else fmt(100 * (value / target - 1), spec)


def ID(v0, key, spec='.4f', target=None):
    """paper_fb.yaml's figure at v0 (bench/results/paper_id/predict.json), or its relative
    difference, %, from ``target``."""
    return F(f'paper_id/predict.json: identified FB at {v0}: {key}',
             lambda: _identified(v0, key, target, spec))


FB = 'FB shared impulse sym3d'
# figures quoted in docs/: (page, text with {} for each number, where each comes from); the page's
# text, its white space collapsed, contains the text
DOC_FIGURES = [
    ('docs/peers.md', 'Converged reference pulse: amplitude {} at t = 0.5 s, speed {} m/s.', [
        J('peers.json', 'reference', 'pulse', 'amplitude', spec='.4f'),
        J('peers.json', 'reference', 'pulse', 'speed_m_s', spec='.4f')]),
    ('docs/peers.md', 'target 1e-3 (the leading pulse is {}).', [
        J('peers.json', 'reference', 'pulse', 'amplitude', spec='.3f')]),
    ('docs/models.md', 'amplitudes {} / {} / {} at 0.5 s (medians {} / {} / {})', [
        *(P(FB, v0, 'amplitude') for v0 in (0.1, 0.125, 0.15)),
        *(P(FB, v0, 'amplitude_median') for v0 in (0.1, 0.125, 0.15))]),
    ('docs/models.md', 'speed {} m/s at v0 = 0.1 (paper 0.248) but flat in v0 ({} at 0.15', [
        P(FB, 0.1, 'speed_m_s'), P(FB, 0.15, 'speed_m_s')]),
    ('docs/paper.md', 'stays the plain reading ({} / {} / {}, {} m/s: `tensegrity paper`)', [
        *(P(FB, v0, 'amplitude') for v0 in (0.1, 0.125, 0.15)), P(FB, 0.1, 'speed_m_s')]),
    ('docs/paper.md', 'at 0.1 m/s amplitude {} ({} %) and speed {} m/s ({} %), at 0.15 m/s '
     'amplitude {} ({} %) and speed {} m/s ({} %)', [
        ID('0.1', 'pulse.amplitude'), ID('0.1', 'pulse.amplitude', '+.1f', 0.054),
        ID('0.1', 'pulse.speed_m_s', '.3f'), ID('0.1', 'pulse.speed_m_s', '+.1f', 0.248),
        ID('0.15', 'pulse.amplitude'), ID('0.15', 'pulse.amplitude', '+.1f', 0.085),
        ID('0.15', 'pulse.speed_m_s', '.3f'), ID('0.15', 'pulse.speed_m_s', '+.1f', 0.372)]),
]


def doc_differences():
    """Figures quoted in docs/ that differ from the result files (the text that should be)."""
    bad = []
    for page, template, getters in DOC_FIGURES:
        text = ' '.join((ROOT / page).read_text(encoding='utf-8').split())
        want = template.format(*(get() for get in getters))
        if want not in text:
            bad.append(f'{page}: lacks {want!r}')
    return bad


def _table_differences(page, want, source):
    """Rows of the markdown table of ``page`` (docs/...) that starts with the header line
    ``want[0]`` and differ from the lines ``want`` made from the result file ``source``: the
    first three, or that the page lacks the table."""
    lines = (ROOT / page).read_text(encoding='utf-8').splitlines()
    start = next((i for i, line in enumerate(lines) if line == want[0]), None)
    if start is None:
        return [f'{page}: lacks the table {want[0]!r}']
    have = []
    for line in lines[start:]:
        if not line.startswith('|'):
            break
        have.append(line)
    return [f'{page}: {h!r} where {source} gives {w!r}'
            for h, w in zip(have + [''] * len(want), want) if h != w][:3]


def paper_table_differences():
    """Rows of docs/models.md's table of ``tensegrity paper --markdown`` that differ from
    bench/results/paper.json (the same command with --json)."""
    from types import SimpleNamespace
    from solver.studies.paper import format_table
    result = dict(_json('paper.json'))
    result['rows'] = [SimpleNamespace(**r) for r in result['rows']]
    want = [line for line in format_table(result, markdown=True).splitlines()
            if line.startswith('|')]
    return _table_differences('docs/models.md', want, 'paper.json')


def trains_table_differences():
    """Rows of docs/physics.md's convergence, sensitivity and ensemble tables that differ from
    the ``convergence``, ``twins`` and ``ensembles`` entries of bench/results/trains.json
    (:func:`bench.trains.convergence_table`, :func:`~bench.trains.sensitivity_table`,
    :func:`~bench.trains.ensemble_table`)."""
    from bench.trains import convergence_table, ensemble_table, sensitivity_table
    trains = _json('trains.json')
    return [d for table in (convergence_table(trains['convergence']),
                            sensitivity_table(trains['convergence'], trains['twins']),
                            ensemble_table(trains['ensembles']))
            for d in _table_differences('docs/physics.md', table, 'trains.json')]


def impacts_table_differences():
    """Rows of docs/physics.md's table of single impacts that differ from
    bench/results/impacts.json (:func:`bench.impacts.table`)."""
    from bench.impacts import table
    return _table_differences('docs/physics.md', table(_json('impacts.json')), 'impacts.json')


def values():
    """{figure: value cell} as the result files give them."""
    return {figure: template.format(*(get() for get in getters))
            for figure, template, getters in ROWS}


def _table_lines(text):
    """(index, cells) of the rows of the README's figure table."""
    lines = text.splitlines()
    start = lines.index('## Current figures')
    for i in range(start, len(lines)):
        if lines[i].startswith('| ') and not lines[i].startswith('| figure |'):
            yield i, [c.strip() for c in re.split(r'(?<!\\)\|', lines[i])[1:-1]]
        elif lines[i].startswith('## ') and i > start:
            return


def readme_values(text=None):
    """{figure: value cell} of the README's table, for the rows :data:`ROWS` names."""
    text = README.read_text(encoding='utf-8') if text is None else text
    out = {}
    for _, cells in _table_lines(text):
        for figure, _, _ in ROWS:
            if cells[0].startswith(figure):
                out[figure] = cells[1]
    return out


def differences(text=None):
    """Rows whose README value differs from the result files' (or that the README lacks)."""
    want, have = values(), readme_values(text)
    return [f'{figure}: README {have.get(figure)!r}, result files {want[figure]!r}'
            for figure in want if have.get(figure) != want[figure]]


def write(path=README):
    text = path.read_text(encoding='utf-8')
    lines = text.splitlines()
    want = values()
    for i, cells in _table_lines(text):
        for figure in want:
            if cells[0].startswith(figure):
                cells[1] = want[figure]
                lines[i] = '| ' + ' | '.join(cells) + ' |'
    path.write_text('\n'.join(lines) + '\n', encoding='utf-8')


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if '--write' in argv:
        write()
    if '--check' in argv:
        bad = (differences() + doc_differences() + paper_table_differences()
               + trains_table_differences() + impacts_table_differences())
        for line in bad:
            print(line)
        return 1 if bad else 0
    for figure, template, getters in ROWS:
        print(f'{figure}: {values()[figure]}')
        for get in getters:
            print(f'    {get.source}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
