"""Shared by the sweep tests (test_sweep.py, test_sweep_cluster.py): the scenes, the end time
of their runs and the figures of a row without its timings."""
from pathlib import Path

from tensegrity_ros.studies import table

ROOT = Path(__file__).resolve().parents[1]
FB = str(ROOT / 'config' / 'scenes' / 'fb_column.yaml')
RB = str(ROOT / 'config' / 'scenes' / 'rb_column.yaml')
T_END = 0.55                      # past t_ref = 0.5 s: every figure is defined
TIMING = table.TIMING_FIELDS


def figures(row):
    """The figures of a sweep row: every field but its timings (which differ from run to run)."""
    return {k: v for k, v in row.items() if k not in TIMING}
