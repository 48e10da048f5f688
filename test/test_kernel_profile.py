"""tools/kernel_profile.py: numba's mangled names read back, perf's report summed by kernel,
and (where perf runs) a profile of a small batch that names the lane kernels it ran."""
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'tools'))
import kernel_profile as kp                      # noqa: E402


def test_numba_names_are_read_back_and_others_are_not_kernels():
    name = ('_ZN6solver7kernels7lanerot16cable_forces_rotB4v303B52c8tJTIeFIjxB2IKSgI4Crv'
            'E5ArrayIdLi3E1C7mutable7alignedE')
    assert kp.demangle(name) == 'solver.kernels.lanerot.cable_forces_rot'
    assert kp.demangle('_ZN5numba7cpython7numbers4implB2v1E') is None
    assert kp.demangle('_PyEval_EvalFrameDefault') is None


def test_the_report_is_summed_by_kernel_over_its_overloads():
    a = '_ZN6solver7kernels5lanes6cablesB4v1E5Array'
    b = '_ZN6solver7kernels5lanes6cablesB4v2E5Array'
    c = '_ZN6solver11integrators8rk4lanes4stepB4v3E'
    report = '\n'.join(['# comment', f'    30.00%  [.] {a}', f'    10.00%  [.] {b}',
                        f'    20.00%  [.] {c}', '    40.00%  [.] _PyEval_EvalFrameDefault'])
    total, rows = kp.shares(report)
    assert total == pytest.approx(60.0)
    assert rows[0][0] == 'solver.kernels.lanes.cables'
    assert rows[0][1] == pytest.approx(100 * 40 / 60) and rows[0][2] == pytest.approx(40.0)
    assert rows[1] == ('solver.integrators.rk4lanes.step', pytest.approx(100 * 20 / 60),
                       pytest.approx(20.0))


def test_a_profile_of_a_small_batch_names_the_lane_kernels():
    if shutil.which('perf') is None:
        pytest.skip('perf is not installed (tools/install_perf.sh)')
    probe = subprocess.run(['perf', 'record', '-q', '-o', '/dev/null', '--', 'true'],
                           capture_output=True)
    if probe.returncode != 0:
        pytest.skip('perf cannot record here (perf_event_paranoid)')
    out = subprocess.run([sys.executable, str(ROOT / 'tools/kernel_profile.py'), '--v0',
                          '0.1', '--points', '4', '--t-end', '0.2'], capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0].startswith('compiled code:')
    kernels = [line.split()[0] for line in lines[2:]]
    # the lanes' force and constraint kernels run in every step of a lane group
    assert any(k.startswith('solver.kernels.lane') for k in kernels), out.stdout
    assert any(k.startswith('solver.integrators.rk4lanes') for k in kernels), out.stdout
