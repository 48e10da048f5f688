"""The Rerun cost benchmark (bench/rerun_overhead.py): its interval of the median, and one short
pair measured for real (both files checked complete by the benchmark itself)."""
import math
import statistics

import numpy as np
import pytest

from bench import rerun_overhead


def test_median_interval_brackets_the_median_and_stays_in_the_data():
    values = list(np.random.default_rng(3).normal(0.15, 0.08, size=31))
    lo, hi = rerun_overhead.median_interval(values)
    assert min(values) <= lo <= statistics.median(values) <= hi <= max(values)
    assert (lo, hi) == rerun_overhead.median_interval(values)          # fixed seed
    wide = rerun_overhead.median_interval(values, level=0.99)
    assert wide[0] <= lo and hi <= wide[1]


def test_median_interval_of_equal_values_is_that_value():
    assert rerun_overhead.median_interval([0.2] * 9) == pytest.approx((0.2, 0.2))


def test_one_short_pair_is_measured_and_checked():
    rows = rerun_overhead.measure(repeats=1, t_end=0.05, log=lambda msg: None)
    assert len(rows) == 1
    row = rows[0]
    assert row['rrd_bytes'] > 0
    for key in ('wall_plain_s', 'wall_rec_s', 'cpu_plain_s', 'cpu_rec_s', 'wall_rec_only_s'):
        assert row[key] > 0 and math.isfinite(row[key])
    assert row['wall_overhead'] == pytest.approx(row['wall_rec_s'] / row['wall_plain_s'] - 1)
    for key in ('others_cores', 'steal_cores'):         # None where /proc/stat is missing
        assert row[key] is None or 0 <= row[key] <= 64
