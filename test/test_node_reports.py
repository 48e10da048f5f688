"""What the node tells: a burst of rejected commands reported by reason and count each second,
the real-time factor and the reason it is behind (pure arithmetic, times given), and an argument
that is not a ROS argument refused with one line."""
import os
import subprocess
import sys

import pytest

from tensegrity_ros.node.realtime import BEHIND, LOG_EVERY_S, RealTime

DOMAIN = 10 + (os.getpid() + 11) % 20


class Lines:
    def __init__(self):
        self.lines = []

    def warning(self, text):
        self.lines.append(text)


def test_a_burst_of_rejections_is_reported_by_reason_and_count_each_second():
    pytest.importorskip('rclpy')
    from tensegrity_ros.node.intake import RejectionTally
    log = Lines()
    tally = RejectionTally(lambda: log)
    tally.add('~/cmd/impact: value 0 is NaN', 0.0)            # the first: at once
    assert log.lines == ['rejected ~/cmd/impact: value 0 is NaN']
    for i in range(20):
        tally.add(f'~/cmd/impact: v0 = {11 + i} m/s is outside [-10, 10]', 0.01 * i)
    for i in range(7):
        tally.add('~/cmd/prestrain: paused, not applied', 0.5)
    tally.flush(0.9)                                         # not a second yet
    assert len(log.lines) == 1
    tally.flush(1.0)
    assert len(log.lines) == 2
    line = log.lines[1]
    assert line.startswith('rejected 27 more commands in the last 1.0 s: ')
    assert '20 x ~/cmd/impact: v0 = 30 m/s is outside [-10, 10]' in line      # the last example
    assert '7 x ~/cmd/prestrain: paused, not applied' in line
    assert line.index('20 x') < line.index('7 x')
    tally.flush(5.0)                                         # nothing new: nothing said
    tally.add('~/cmd/focus: the point must be finite', 5.0)   # quiet for a second: at once
    assert len(log.lines) == 3 and log.lines[2] == 'rejected ~/cmd/focus: the point must be finite'


def test_real_time_factor_over_the_window_and_the_reason():
    rt = RealTime(rest_step_cost=1e-5, n_columns=1, n_nodes=153, window_s=2.0)
    for i in range(301):                       # 3 s of frames, the clock at 0.25x
        rt.sample(0.01 * i, 0.0025 * i)
    assert rt.factor() == pytest.approx(0.25, rel=1e-9)
    assert 1.99 <= rt.span_s <= 2.0
    costs = (6.25e-4, 4e-3, 1e-4, 200.0)          # dt, step, frame, publish rate
    msg, log = rt.status(3.0, 1.0, True, *costs)
    assert msg.startswith('behind real time: 0.25x') and 'target 1x' in msg
    assert 'contact sub-steps' in msg and log is not None
    assert rt.status(4.0, 1.0, True, *costs)[1] is None          # throttled
    assert rt.status(4.0 + LOG_EVERY_S, 1.0, True, *costs)[1] is not None
    assert rt.status(3.0, 0.25 / BEHIND, True, *costs) == (None, None)   # at 0.9
    assert rt.status(3.0, 0.0, True, *costs) == (None, None)     # as fast as can
    assert rt.status(3.0, 1.0, False, *costs) == (None, None)    # paused
    big = RealTime(rest_step_cost=3e-3, n_columns=5, n_nodes=765)
    assert big.reason(1.0, 6.25e-4, 3.5e-3, 1e-4, 200.0).startswith('array size: 5 columns of 765')
    calm = RealTime(rest_step_cost=1e-5, n_columns=1, n_nodes=153)
    assert calm.reason(1.0, 6.25e-4, 1.2e-5, 5e-3, 200.0).startswith('publishing')
    assert calm.reason(1.0, 6.25e-4, 1.2e-5, 1e-4, 200.0).startswith('CPU time: stepping and '
                                                                     'publishing need 4 %')
    # an array's stepping call costs its fixed part every tick: 5 ms at 200 Hz is all of it
    slow = calm.reason(1.0, 6.25e-4, 1.2e-5, 1e-4, 200.0, call_cost=5e-3)
    assert slow.startswith('publishing') and '5 ms per stepping call' in slow
    rt.restart()
    assert rt.factor() is None


@pytest.mark.parametrize('args, says', [
    (['--foo'], 'unknown argument --foo'),
    (['extra', '--ros-args', '-p', 'dt:=0'], 'unknown argument extra'),
    (['--ros-args', '--bogus'], "unknown ROS argument '--bogus'"),
])
def test_node_refuses_an_argument_that_is_not_a_ros_argument(args, says):
    pytest.importorskip('rclpy')
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    r = subprocess.run([sys.executable, '-m', 'tensegrity_ros.node.node', *args], env=env,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and says in lines[0], r.stderr
    assert lines[0].startswith('tensegrity_node: ') and 'Traceback' not in r.stderr
