"""The soak (bench/soak.py) in short: the node at real_time_factor 0 recording MCAP and Rerun,
flooded with 1,000 commands per second (valid, diverging, malformed, resets, parameter changes)
for 8 s. The node stays alive, publishes and records nothing non-finite, both files are complete
and hold the same frames, and the node starts no other process. (Rates are reported by
``python -m bench.soak``, not asserted: they depend on the machine.)"""
import os

import pytest

pytest.importorskip('rclpy')
pytest.importorskip('rerun')
pytest.importorskip('psutil')


def test_short_soak(tmp_path):
    from bench.soak import soak
    r = soak(8.0, 1000.0, out_dir=tmp_path, domain_id=150 + os.getpid() % 50, warmup_s=1.0,
             log=lambda *a: None)
    assert r['node_alive'] and r['node_exit_code'] == 0
    assert r['sent']['total'] >= 5_000
    f = r['files']
    assert f['mcap']['complete'] and f['rerun']['complete']
    assert f['mcap']['frames'] > 0 and f['mcap']['frames'] == f['rerun']['frames']
    assert f['mcap']['non_finite'] == f['rerun']['non_finite'] == 0
    assert r['strain_non_finite_received'] == 0
    assert r['commands']['rejected'] > 0 and r['commands']['accepted'] > 0
    assert r['start']['helpers'] == [] and r['helpers_left'] == []
