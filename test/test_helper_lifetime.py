"""The Rerun recorder's helper processes never outlive the process that owns them, and never
accumulate: the owner killed by any signal leaves a complete file of what it handed over and no
helper, even when a process it forked still holds its end of the socket; a process keeps at most
one idle helper, and none after it exits."""
import os
import signal
import subprocess
import sys
import time

import pytest

from mcap_helpers import ROOT

pytest.importorskip('rerun')

from test_long_recordings import rrd_times  # noqa: E402

OWNER = '''
import os, sys, time
sys.path.insert(0, {test!r})
from mcap_helpers import small_network, synthetic_frames
from tensegrity_ros.io.rerun_log import RerunRecorder
net = small_network(3)
rec = RerunRecorder(net, {path!r}, flush_every=50, max_latency_s=1e9)
for f in synthetic_frames(net, 120, dt=0.005):
    rec.frame(f)
rec.sync()                                  # two batches handed over, 20 frames buffered
child = os.fork()                           # holds every descriptor of the owner, the socket too
if child == 0:
    time.sleep(120)
    os._exit(0)
print(rec._helper.proc.pid, child, flush=True)
time.sleep(120)
'''


def running(pid):
    """Whether process ``pid`` exists and is not a zombie (Linux)."""
    try:
        with open(f'/proc/{pid}/stat') as f:
            return f.read().rsplit(')', 1)[1].split()[0] != 'Z'
    except OSError:
        return False


def wait_gone(pid, timeout_s=30):
    deadline = time.monotonic() + timeout_s
    while running(pid):
        if time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True


@pytest.mark.parametrize('sig', [signal.SIGKILL, signal.SIGTERM, signal.SIGINT])
def test_an_owner_killed_by_any_signal_leaves_its_file_and_no_helper(tmp_path, sig):
    path = tmp_path / 'owner.rrd'
    code = OWNER.format(test=str(ROOT / 'test'), path=str(path))
    proc = subprocess.Popen([sys.executable, '-c', code], cwd=ROOT, stdout=subprocess.PIPE,
                            text=True, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    child = None
    try:
        helper, child = map(int, proc.stdout.readline().split())
        assert running(helper) and running(child)
        proc.send_signal(sig)
        proc.wait(timeout=30)
        assert wait_gone(helper), 'the helper outlived its owner'
        assert running(child)                   # the socket was still open: the helper saw the
    finally:                                    # owner go, not the end of the connection
        proc.kill()
        proc.wait(timeout=30)
        if child is not None and running(child):
            os.kill(child, signal.SIGKILL)
    assert rrd_times(path) == [k * 5_000_000 for k in range(100)]


def test_helpers_do_not_accumulate(tmp_path):
    """Sequential recordings reuse one helper; after two at once, one helper stays idle and the
    other exits; after the owner exits, none is left."""
    code = f'''
import sys
sys.path.insert(0, {str(ROOT / 'test')!r})
import psutil
from mcap_helpers import small_network, synthetic_frames
from tensegrity_ros.io import rerun_log
from tensegrity_ros.io.rerun_log import RerunRecorder
net = small_network(3)
frames = synthetic_frames(net, 30, dt=0.005)
pids = set()
for k in range(3):
    with RerunRecorder(net, {str(tmp_path)!r} + f'/seq{{k}}.rrd') as rec:
        for f in frames:
            rec.frame(f)
    pids.add(rec._helper.proc.pid)
a = RerunRecorder(net, {str(tmp_path)!r} + '/a.rrd')
b = RerunRecorder(net, {str(tmp_path)!r} + '/b.rrd')
for f in frames:
    a.frame(f)
    b.frame(f)
a.close()
b.close()
pids |= {{a._helper.proc.pid, b._helper.proc.pid}}
alive = [p for p in psutil.Process().children() if p.status() != psutil.STATUS_ZOMBIE]
print(len(pids), len(alive), len(rerun_log._IDLE), *sorted(pids), flush=True)
'''
    r = subprocess.run([sys.executable, '-c', code], cwd=ROOT, capture_output=True, text=True,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=240)
    assert r.returncode == 0, r.stderr
    n_pids, n_alive, n_idle, *pids = map(int, r.stdout.split())
    assert (n_pids, n_alive, n_idle) == (2, 1, 1)
    for pid in pids:
        assert wait_gone(pid, 10), f'helper {pid} outlived its owner'
    for name in ('seq0', 'seq1', 'seq2', 'a', 'b'):
        assert rrd_times(tmp_path / f'{name}.rrd') == [k * 5_000_000 for k in range(30)]
