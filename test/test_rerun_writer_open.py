"""The recording helper's writer, in this process: a recording whose opening fails after its
stream exists reports that error and still closes (no AttributeError while closing)."""
import os

import numpy as np
import pytest

pytest.importorskip('rerun')
from solver.build.scene import Scene  # noqa: E402
from solver.simulate.array import simulation_for
from tensegrity_ros.io import rerun_writer  # noqa: E402

FB = os.path.join(os.path.dirname(__file__), '..', 'config', 'scenes', 'fb_column.yaml')


class _Conn:
    def __init__(self):
        self.sent = []

    def send(self, msg):
        self.sent.append(msg)


def test_an_open_that_fails_after_the_stream_exists_is_reported_and_closes(tmp_path,
                                                                           monkeypatch):
    sim = simulation_for(Scene.load(FB).with_overrides(['structure.n_prisms=3', 'model=full3d']))
    net = sim.network
    f = sim.frame()
    shapes = (f.positions.shape, f.strain.shape, f.tension.shape)

    def broken(*args, **kwargs):
        raise RuntimeError('blueprint refused')
    monkeypatch.setattr(rerun_writer, 'blueprint', broken)
    buffer_shape = (2, 4, 8)
    memfd = os.memfd_create('test-writer')
    os.ftruncate(memfd, 8 * int(np.prod(buffer_shape)))
    conn = _Conn()
    w = rerun_writer._Writer(conn, memfd, os.sched_getaffinity(0), net, str(tmp_path / 'x.rrd'),
                             None, 1.0, 4, 16, 0.1, shapes, buffer_shape, None, 'test', 'rec',
                             True)
    assert conn.sent and conn.sent[0][0] == 'error' and 'blueprint refused' in conn.sent[0][1]
    message = w._close(None, 0)                  # raised AttributeError (_wave) before
    assert 'blueprint refused' in message
