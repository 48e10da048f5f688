"""Frame -> ROS messages (tensegrity_ros.msgs.messages) and command parsing
(tensegrity_ros.node.commands):
round trips, layouts against their definition, marker geometry, nothing non-finite."""
import math

import numpy as np
import pytest

pytest.importorskip('rclpy')
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from std_msgs.msg import Float64MultiArray  # noqa: E402

from solver.build.scene import Scene  # noqa: E402
from solver.simulate.array import simulation_for
from tensegrity_ros.node import commands  # noqa: E402
from tensegrity_ros.msgs import messages, style


@pytest.fixture(scope='module')
def sim():
    s = simulation_for(Scene.load('config/scenes/fb_column.yaml').with_overrides(
        ['structure.n_prisms=6', 'structure.n_columns=2']))
    s.apply_impact(0.1)
    s.advance(0.03)
    return s


def test_frame_messages_round_trip(sim):
    f = sim.frame()
    net = sim.network
    msgs = messages.frame_messages(f, net, markers=True, clock=True)
    assert set(msgs) == {'~/nodes', '~/strain', '~/cable_tension', '~/markers', '/clock',
                         '~/base_force', '~/energy'}
    e = msgs['~/energy']
    assert [(d.label, d.size) for d in e.layout.dim] == [
        ('energy_J,constraint_error,energy_balance_error', 3)]
    assert list(e.data) == [f.energy, f.constraint_error, f.energy_balance_error]
    b = msgs['~/base_force']
    assert [(d.label, d.size) for d in b.layout.dim] == [('column', net.n_columns)]
    np.testing.assert_array_equal(np.array(b.data), f.base_force)
    for key, msg in msgs.items():
        assert messages.TYPES[key].split('/')[-1] == type(msg).__name__
        back = deserialize_message(serialize_message(msg), type(msg))
        if key == '~/markers':            # colours are float32 on the wire: compare geometry
            assert deserialize_message(serialize_message(back), type(msg)) == back
            assert [m.points for m in back.markers] == [m.points for m in msg.markers]
        else:
            assert back == msg
    stamp = msgs['~/nodes'].header.stamp
    assert messages.stamp_to_ns(stamp) == round(f.t * 1e9) and msgs['/clock'].clock == stamp
    assert msgs['~/nodes'].header.frame_id == 'world'
    x = messages.cloud_positions(msgs['~/nodes'])
    assert np.array_equal(x, f.positions.astype(np.float32).astype(np.float64))
    s = msgs['~/strain']
    dims = [(d.label, d.size, d.stride) for d in s.layout.dim]
    assert dims == [('column', 2, 12), ('prism', 6, 6)]
    # the MultiArrayLayout definition: element [c, i] is data[offset + stride_1 * c + i]
    data = np.asarray(s.data)
    for c in range(2):
        for i in range(6):
            assert data[s.layout.data_offset + dims[1][2] * c + i] == f.strain[c, i]
    t = msgs['~/cable_tension']
    assert [(d.label, d.size) for d in t.layout.dim] == [('cable', net.n_cables)]
    assert np.array_equal(np.asarray(t.data), f.tension)


def test_markers_cover_every_member_with_binned_colours(sim):
    f = sim.frame()
    net = sim.network
    t_max = style.reference_tension_scale(net)
    arr = messages.marker_array(f, net, messages.sim_stamp(f.t), t_max)
    bars = [m for m in arr.markers if m.ns == 'bars']
    cables = [m for m in arr.markers if m.ns == 'cables']
    assert len(bars) == 1 and len(bars[0].points) == 2 * (net.n_bars + net.n_edges)
    assert len(cables) == messages.N_BINS + 1
    assert sum(len(m.points) for m in cables) == 2 * net.n_cables
    ends = {}
    for m in cables:
        for p, q in zip(m.points[0::2], m.points[1::2]):
            ends[(round(p.x, 12), round(p.y, 12), round(p.z, 12),
                  round(q.x, 12), round(q.y, 12), round(q.z, 12))] = m.id
    for c in range(net.n_cables):
        a, b = f.positions[net.cable_a[c]], f.positions[net.cable_b[c]]
        k = ends[tuple(np.round(np.concatenate([a, b]), 12))]
        T = f.tension[c]
        if T <= 0:
            assert k == 0
        else:                            # bin k covers tensions in [(k-1), k) * t_max / N_BINS
            lo, hi = (k - 1) * t_max / messages.N_BINS, k * t_max / messages.N_BINS
            assert lo <= min(T, t_max) <= hi


def test_non_finite_frame_is_refused(sim):
    f = sim.frame()
    f.strain = f.strain.copy()
    f.strain[0, 1] = np.nan
    with pytest.raises(ValueError, match='strain is not finite'):
        messages.frame_messages(f, sim.network)
    d = messages.diagnostics_message(messages.sim_stamp(0.5), {'energy_J': math.nan, 'n': 3})
    assert [kv.value for kv in d.status[0].values] == ['n/a', '3']


def test_topic_names_and_command_arrays():
    assert messages.resolve_topic('~/cmd/impact') == '/tensegrity/tensegrity_sim/cmd/impact'
    assert messages.resolve_topic('/clock') == '/clock'
    msg = messages.command_array([0.1, 0.2], 'column')
    assert isinstance(msg, Float64MultiArray) and msg.layout.dim[0].label == 'column'
    assert np.allclose(commands.parse_impact(msg.data, msg.layout, 2), [0.1, 0.2])


@pytest.mark.parametrize('data,label,n_cols,match', [
    ([], '', 1, 'empty'), ([0.1, 0.1], '', 3, 'expected 1 or 3'), ([math.nan], '', 1, 'NaN'),
    ([math.inf], '', 1, 'infinite'), ([10.5], '', 1, 'outside'), ([0.1], 'bogus', 1, 'label'),
    ([0.1, 0.1], 'all', 2, 'expected 1')])
def test_impact_parser_names_the_problem(data, label, n_cols, match):
    msg = messages.command_array(data, label) if data else Float64MultiArray()
    with pytest.raises(commands.CommandError, match=match):
        commands.parse_impact(msg.data, msg.layout, n_cols)


def test_prestrain_parser_forms():
    cross_prism = np.repeat(np.arange(4), 3)               # 2 columns x 2 prisms x 3 cables
    p = commands.parse_prestrain([0.003], None, 2, 2, cross_prism)
    assert np.array_equal(p, np.full((2, 2), 0.003))
    p = commands.parse_prestrain([0.001, 0.004], None, 2, 2, cross_prism)
    assert np.array_equal(p, [[0.001, 0.001], [0.004, 0.004]])
    per_cable = np.repeat([0.001, 0.002, 0.003, 0.004], 3)
    p = commands.parse_prestrain(per_cable, None, 2, 2, cross_prism)
    assert np.array_equal(p, [[0.001, 0.002], [0.003, 0.004]])
    per_cable[7] = 0.0035                                   # prism 0 of column 1 now uneven
    with pytest.raises(commands.CommandError, match='prism 0 of column 1'):
        commands.parse_prestrain(per_cable, None, 2, 2, cross_prism)
    for bad, match in (([0.0], 'outside'), ([0.51], 'outside'), ([0.1] * 5, 'expected 1, 2')):
        with pytest.raises(commands.CommandError, match=match):
            commands.parse_prestrain(bad, None, 2, 2, cross_prism)


def test_marker_bytes_equal_marker_objects(sim):
    """The NumPy CDR writer against rclpy's own serializer: same message after deserialization,
    same length (bytes may differ only in padding)."""
    from visualization_msgs.msg import MarkerArray

    from tensegrity_ros.msgs.cdr import marker_array_cdr
    sim.reset()
    sim.apply_impact(0.15)
    for _ in range(6):                  # at rest, then cables moving between colour bins
        f = sim.frame()
        stamp = messages.sim_stamp(f.t)
        obj = messages.marker_array(f, sim.network, stamp)
        raw = marker_array_cdr(f, sim.network, stamp)
        ref = serialize_message(obj)
        assert len(raw) == len(ref)
        assert deserialize_message(raw, MarkerArray) == deserialize_message(ref, MarkerArray)
        sim.advance(0.01)


@pytest.mark.parametrize('markers,clock', [(False, False), (True, True)])
def test_frame_bytes_equal_frame_objects(sim, markers, clock):
    """Every serialized frame message against rclpy's serializer of the message objects: the same
    keys, the same length, the same message after deserialization."""
    from tensegrity_ros.msgs.cdr import frame_messages_cdr
    sim.apply_impact(0.1)
    sim.advance(0.02)
    f = sim.frame()
    objs = messages.frame_messages(f, sim.network, markers=markers, clock=clock)
    raw = frame_messages_cdr(f, sim.network, markers=markers, clock=clock)
    assert sorted(raw) == sorted(objs)
    for key, obj in objs.items():
        ref = serialize_message(obj)
        assert len(raw[key]) == len(ref), key
        assert deserialize_message(raw[key], type(obj)) == deserialize_message(ref, type(obj))


def test_frame_bytes_refuse_a_non_finite_frame(sim):
    from tensegrity_ros.msgs.cdr import frame_messages_cdr
    f = sim.frame()
    f.strain[0, 3] = float('nan')
    with pytest.raises(ValueError, match='strain is not finite'):
        frame_messages_cdr(f, sim.network)


def test_a_non_finite_base_force_is_never_published(sim):
    from tensegrity_ros.msgs.cdr import frame_messages_cdr
    f = sim.frame()
    f.base_force[1] = float('inf')
    for build in (messages.frame_messages, frame_messages_cdr):
        with pytest.raises(ValueError, match='base_force is not finite'):
            build(f, sim.network)
