"""The node's console script stops on SIGINT / SIGTERM after the tick that runs (a flag, not an
exception in the middle of a callback, so both recordings end on the same frame); a second
signal interrupts at once."""
import os
import signal

import pytest

pytest.importorskip('rclpy')
from tensegrity_ros.node.node import _stop_on_signals  # noqa: E402


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_a_signal_sets_the_stop_flag_and_a_second_one_interrupts(sig):
    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        stop = _stop_on_signals()
        assert stop == []
        os.kill(os.getpid(), sig)          # handled at the next bytecode: no exception here
        for _ in range(1000):
            if stop:
                break
        assert stop == [sig]
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), sig)
            for _ in range(1000):
                pass
    finally:
        for s, h in saved.items():
            signal.signal(s, h)
