"""Shared helpers of the MCAP tests: synthetic frames of a real network, a field-by-field message
comparison, and a recorded log with the list of what was written."""
from __future__ import annotations

import array
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
FLOAT32_TYPES = ('float', 'sequence<float>')


def small_network(n_prisms=3):
    """The network of the prism scene stacked to ``n_prisms`` (no time stepping, no numba)."""
    from solver.build.scene import Scene
    from solver.build.structures import build_network
    scene = Scene.load(ROOT / 'config' / 'scenes' / 'prism.yaml')
    return build_network(scene.with_overrides([('structure.n_prisms', n_prisms)]))


def synthetic_frames(net, n, dt=0.01, seed=0):
    """``n`` frames with known, distinct values (not from the solver): positions x0 + noise,
    strain, tension and base force random (some cables slack), t = k * dt."""
    from solver.simulate.simulation import Frame
    rng = np.random.default_rng(seed)
    frames = []
    for k in range(n):
        tension = rng.uniform(0.0, 5.0, net.n_cables)
        tension[rng.random(net.n_cables) < 0.2] = 0.0
        frames.append(Frame(t=k * dt, step=10 * k,
                            positions=net.x0 + 1e-4 * rng.standard_normal(net.x0.shape),
                            strain=rng.uniform(-0.05, 0.01, (net.n_columns, net.n_prisms)),
                            tension=tension, energy=1.0 + 0.01 * k,
                            constraint_error=1e-12 * (k + 1),
                            base_force=rng.uniform(-0.01, 0.05, net.n_columns)))
    return frames


class Capture:
    """A recorder stand-in that keeps (topic, msg, stamp_ns) and forwards to a real recorder."""

    def __init__(self, recorder):
        self.rec = recorder
        self.written = []
        self.classes = {}

    def declare(self, topic, cls, qos=None):
        self.classes[topic] = cls
        self.rec.declare(topic, cls, qos)

    def write(self, topic, msg, stamp_ns):
        self.written.append((topic, msg, int(stamp_ns)))
        self.rec.write(topic, msg, stamp_ns)

    def write_serialized(self, topic, data, stamp_ns):
        """Kept as the message rclpy deserializes from the bytes (what a reader must get)."""
        from rclpy.serialization import deserialize_message
        self.written.append((topic, deserialize_message(data, self.classes[topic]),
                             int(stamp_ns)))
        self.rec.write_serialized(topic, data, stamp_ns)


def record_frames(path, frames, net, marker_every=2, with_network=True, **kw):
    """Write ``frames`` and an impact command (t = 0) with FrameLog (and the network metadata
    unless ``with_network`` is false); returns what was written."""
    from tensegrity_ros.io.mcap_frames import FrameLog, network_metadata
    from tensegrity_ros.io.mcap_writer import McapRecorder
    meta = network_metadata(net, 'test') if with_network else None
    with McapRecorder(path, metadata=meta, **kw) as rec:
        cap = Capture(rec)
        log = FrameLog(cap, net, marker_every=marker_every)
        log.command('~/cmd/impact', [0.1], 'all', frames[0], 'impact v0 = 0.1 m/s')
        for f in frames:
            log.frame(f)
    return cap.written


def same(a, b, ftype='', path='msg'):
    """Assert that message ``b`` (rclpy or mcap_ros2 decoded) holds the values of rclpy message
    ``a``; float32 fields compare after rounding to float32, the way they travel."""
    if hasattr(a, 'get_fields_and_field_types'):
        for name, t in a.get_fields_and_field_types().items():
            same(getattr(a, name), getattr(b, name), t, f'{path}.{name}')
    elif isinstance(a, (bytes, bytearray)) and ftype == 'octet':
        assert a[0] == (b if isinstance(b, int) else b[0]), path
    elif isinstance(a, (list, tuple, array.array, np.ndarray, bytes)):
        assert len(a) == len(b), f'{path}: length {len(a)} != {len(b)}'
        if len(a) and hasattr(a[0], 'get_fields_and_field_types'):
            for i, (x, y) in enumerate(zip(a, b)):
                same(x, y, '', f'{path}[{i}]')
        else:
            dt = np.float32 if ftype in FLOAT32_TYPES else None
            xa = np.frombuffer(bytes(a), np.uint8) if isinstance(a, bytes) else np.asarray(a, dt)
            xb = np.frombuffer(bytes(b), np.uint8) if isinstance(b, bytes) else np.asarray(b, dt)
            assert np.array_equal(xa, xb), path
    elif ftype == 'float':
        assert np.float32(a) == np.float32(b), f'{path}: {a} != {b}'
    else:
        assert a == b, f'{path}: {a!r} != {b!r}'
