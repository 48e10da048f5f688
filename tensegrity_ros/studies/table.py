"""The rows of a sweep: which figures of a run summary a row keeps, the append-only
``rows.jsonl`` a sweep resumes from, and the Parquet and CSV tables written from it."""
from __future__ import annotations

import json
import os
from pathlib import Path

ROWS = 'rows.jsonl'
TABLE = 'results.parquet'
CSV = 'results.csv'
# top-level figures of the run summary a row keeps (besides every ``pulse.*`` figure)
SUMMARY_FIELDS = ('energy_drift_rel', 'energy_balance_error', 'constraint_error_rel',
                  'wall_time_s', 'real_time_factor', 'steps', 'steps_taken', 'contacts_met',
                  'model', 'integrator', 'dt', 't_end')
PULSE_FIELDS = ('amplitude', 'amplitude_median', 'amplitude_min', 'amplitude_max',
                'amplitude_passage_max', 'speed_m_s', 'speed_snapshot_m_s', 'speed_arrival_m_s',
                'width_prisms', 'width_half_prisms', 'width_10_prisms', 't_ref',
                'arrival_time_s', 'arrival_end_s', 'speed_paper_m_s', 'front_speed_m_s',
                'front_amplitude', 'front_arrival_s', 'momentum_strain',
                'momentum_nodes', 'momentum_ratio', 'width_eff_prisms', 'momentum_share',
                'momentum_prisms', 'momentum_column')
# the fields of a row that depend on the machine and the moment, not on the point
TIMING_FIELDS = ('wall_time_s', 'real_time_factor', 'task_wall_s', 'cpu_time_s', 'worker_pid')
# the numeric figures a fit may use, named as in the summary
FIGURES = tuple(f'pulse.{k}' for k in PULSE_FIELDS if k != 't_ref') + (
    'energy_drift_rel', 'constraint_error_rel')


def flatten(summary):
    """The figures of a run's ``RunSummary`` a row holds, in their JSON form (None where not
    finite): ``SUMMARY_FIELDS`` and ``pulse.*``."""
    figures = summary.to_json()
    row = {k: figures[k] for k in SUMMARY_FIELDS}
    pulse = figures['pulse'] or {}
    for k in PULSE_FIELDS:
        row[f'pulse.{k}'] = pulse.get(k)
    return row


def empty_figures():
    row = {k: None for k in SUMMARY_FIELDS}
    row.update({f'pulse.{k}': None for k in PULSE_FIELDS})
    return row


def read_rows(out_dir):
    """The rows already in ``out_dir`` (``rows.jsonl``), by point id (the last row of an id
    wins; a line cut short by a kill is ignored)."""
    path = Path(out_dir) / ROWS
    rows = {}
    if not path.exists():
        return rows
    for line in path.read_text().splitlines():
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(row, dict) and row.get('point_id'):
            rows[row['point_id']] = row
    return rows


def write_table(out_dir, rows, columns):
    """``results.parquet`` and ``results.csv`` from ``rows`` (dicts), columns in ``columns``
    order first; each written to a temporary file and renamed, so a reader never sees half a
    table."""
    import pyarrow as pa
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq
    out_dir = Path(out_dir)
    names = list(columns) + sorted({k for r in rows for k in r} - set(columns))
    data = {}
    for name in names:
        col = [r.get(name) for r in rows]
        kinds = {type(v) for v in col if v is not None}
        if kinds and kinds <= {int, float} and float in kinds:
            col = [None if v is None else float(v) for v in col]
        elif len(kinds) > 1:
            col = [None if v is None else str(v) for v in col]
        data[name] = col
    table = pa.table(data) if rows else pa.table({n: pa.array([], pa.null()) for n in names})
    tmp = out_dir / (TABLE + '.tmp')
    pq.write_table(table, tmp)
    os.replace(tmp, out_dir / TABLE)
    tmp = out_dir / (CSV + '.tmp')
    pacsv.write_csv(table, tmp)
    os.replace(tmp, out_dir / CSV)
