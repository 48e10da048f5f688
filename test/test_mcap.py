"""MCAP logs (docs/interfaces.md section 5): round trip, decoding by two independent decoders, the
ROS 2 profile records, truncated files, and Rerun's own MCAP loader."""
import json

import numpy as np
import pytest
import yaml

from mcap_helpers import record_frames, same, small_network, synthetic_frames

pytest.importorskip('rclpy')
mcap_reader = pytest.importorskip('mcap.reader')

from tensegrity_ros.msgs import messages as M  # noqa: E402
from tensegrity_ros.msgs import style  # noqa: E402
from tensegrity_ros.io.mcap_reader import LogError, McapLog, load_run  # noqa: E402
from tensegrity_ros.io.bag_format import DELIMITER, full_definition, qos_yaml, share_dir  # noqa: E402
from tensegrity_ros.io.mcap_writer import McapRecorder, RecordingError  # noqa: E402


@pytest.fixture(scope='module')
def net():
    return small_network(3)


@pytest.fixture(scope='module')
def frames(net):
    return synthetic_frames(net, 12)


@pytest.fixture(scope='module')
def log(tmp_path_factory, net, frames):
    path = tmp_path_factory.mktemp('mcap') / 'run.mcap'
    written = record_frames(path, frames, net, marker_every=3)
    return path, written


def test_round_trip_what_was_published_is_what_the_loader_reads(log, frames, net):
    path, written = log
    run = load_run(path)
    assert not run.truncated
    t = np.array([f.t for f in frames])
    np.testing.assert_array_equal(run.time, np.round(t * 1e9).astype(np.int64) / 1e9)
    np.testing.assert_array_equal(run.strain, np.stack([f.strain for f in frames]))
    np.testing.assert_array_equal(run.tensions, np.stack([f.tension for f in frames]))
    # positions travel as float32 (PointCloud2)
    pos = np.stack([f.positions for f in frames]).astype(np.float32).astype(np.float64)
    np.testing.assert_array_equal(run.positions, pos)
    assert run.positions.shape == (len(frames), net.n_nodes, 3)
    assert list(run.command_topic) == ['impact'] and run.command_values[0].tolist() == [0.1]
    assert run.command_time.tolist() == [0.0]
    counts = {}
    for topic, _, _ in written:
        counts[topic] = counts.get(topic, 0) + 1
    assert run.topics == counts
    assert counts[M.resolve_topic('~/markers')] == 4          # frames 0, 3, 6, 9


def test_every_message_decodes_with_mcap_ros2_and_rclpy(log):
    from rclpy.serialization import deserialize_message
    path, written = log
    reader_log = McapLog(path)
    got = list(reader_log.messages())
    assert len(got) == len(written)
    for m, (topic, msg, stamp) in zip(got, written):
        assert (m.topic, m.log_time_ns) == (topic, stamp)
        assert m.type_name == M.TYPES[next(k for k in M.TYPES if M.resolve_topic(k) == topic)]
        same(msg, reader_log.decode(m), path=topic)                     # mcap_ros2 decoder
        same(msg, deserialize_message(m.data, type(msg)), path=topic)   # rclpy


def test_file_is_ros2_profile_with_summary_statistics_and_qos(log):
    path, written = log
    with open(path, 'rb') as f:
        reader = mcap_reader.make_reader(f)
        assert reader.get_header().profile == 'ros2'
        summary = reader.get_summary()
    stats = summary.statistics
    assert stats.message_count == len(written)
    # declared, nothing written: the prestrain command and the events
    assert stats.channel_count == len(summary.channels) == len({t for t, _, _ in written}) + 2
    assert {c.topic for c in summary.channels.values()} - {t for t, _, _ in written} == {
        '/tensegrity/tensegrity_sim/cmd/prestrain', '/tensegrity/tensegrity_sim/events'}
    assert stats.chunk_count == len(summary.chunk_indexes) >= 1
    assert stats.message_end_time == max(s for _, _, s in written)
    by_topic = {c.topic: c for c in summary.channels.values()}
    for topic, cid_count in ((t, sum(1 for w in written if w[0] == t)) for t in by_topic):
        assert stats.channel_message_counts.get(by_topic[topic].id, 0) == cid_count
    for ch in summary.channels.values():
        assert ch.message_encoding == 'cdr'
        schema = summary.schemas[ch.schema_id]
        assert schema.encoding == 'ros2msg'
        assert schema.data.decode() == full_definition(schema.name)
        qos = yaml.safe_load(ch.metadata['offered_qos_profiles'])
        assert qos[0]['reliability'] == 'reliable' and qos[0]['depth'] == 10
        assert ch.metadata['topic_type_hash'].startswith('RIHS01_')


@pytest.mark.parametrize('type_name', sorted(set(M.TYPES.values())))
def test_full_definition_holds_every_nested_type_once(type_name):
    """Checked against the type's .json description (rosidl's own list of referenced types)."""
    pkg, _, typ = type_name.split('/')
    text = full_definition(type_name)
    desc = json.loads((share_dir() / pkg / 'msg' / f'{typ}.json').read_text())
    nested = {t['type_name'] for t in desc['type_description_msg']['referenced_type_descriptions']}
    sections = text.split('\n' + DELIMITER)
    assert sections[0] == (share_dir() / pkg / 'msg' / f'{typ}.msg').read_text()
    names = [s.split('\n', 1)[0] for s in sections[1:]]
    assert all(n.startswith('MSG: ') for n in names)
    names = [n[5:] for n in names]
    assert len(names) == len(set(names))
    assert {n.replace('/', '/msg/') for n in names} == nested
    for name, body in zip(names, sections[1:]):
        p, t = name.split('/')
        assert body.split('\n', 1)[1].startswith((share_dir() / p / 'msg' / f'{t}.msg')
                                                 .read_text())


def test_qos_yaml_states_the_profile():
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from tensegrity_ros.node.replay import qos_from_yaml
    q = QoSProfile(depth=7, reliability=ReliabilityPolicy.BEST_EFFORT,
                   durability=DurabilityPolicy.TRANSIENT_LOCAL)
    p = yaml.safe_load(qos_yaml(q))
    assert p == [{'history': 'keep_last', 'depth': 7, 'reliability': 'best_effort',
                  'durability': 'transient_local',
                  'deadline': {'sec': 9223372036, 'nsec': 854775807},
                  'lifespan': {'sec': 9223372036, 'nsec': 854775807},
                  'liveliness': 'automatic',
                  'liveliness_lease_duration': {'sec': 9223372036, 'nsec': 854775807},
                  'avoid_ros_namespace_conventions': False}]
    back = qos_from_yaml(qos_yaml(q))
    assert (back.depth, back.reliability, back.durability) == (7, q.reliability, q.durability)


def test_truncated_file_reads_exactly_its_complete_chunks(tmp_path, net, frames):
    """Cut a finished file inside each chunk in turn: the loader returns the messages of the
    chunks that end before the cut (from the full file's chunk index), no more, no fewer."""
    path = tmp_path / 'full.mcap'
    written = record_frames(path, frames, net, marker_every=3, chunk_size=4096)
    data = path.read_bytes()
    with open(path, 'rb') as f:
        chunks = sorted(mcap_reader.make_reader(f).get_summary().chunk_indexes,
                        key=lambda c: c.chunk_start_offset)
    assert len(chunks) >= 3
    n_frames = []
    for ci in chunks:
        cut = ci.chunk_start_offset + ci.chunk_length // 2
        part = tmp_path / 'cut.mcap'
        part.write_bytes(data[:cut])
        done = [c for c in chunks if c.chunk_start_offset + c.chunk_length <= cut]
        log = McapLog(part)
        got = list(log.messages())
        assert log.truncated
        n_expected = _messages_in(data, done)
        assert len(got) == n_expected
        assert [(m.topic, m.log_time_ns) for m in got] == [(w[0], w[2])
                                                           for w in written[:n_expected]]
        run = load_run(part)
        assert run.truncated and len(run.time) <= len(frames)
        n_frames.append(len(run.time))
        if len(run.time):
            np.testing.assert_array_equal(run.strain, np.stack([f.strain for f in frames])
                                          [:len(run.time)])
    assert n_frames[-1] > 0 and n_frames == sorted(n_frames)


def _messages_in(data, chunk_indexes):
    """Messages inside the given chunks, counted from their records (mcap's chunk parser)."""
    import io

    from mcap.exceptions import EndOfFile
    from mcap.records import Message
    from mcap.stream_reader import StreamReader
    n = 0
    for ci in chunk_indexes:
        raw = data[ci.chunk_start_offset:ci.chunk_start_offset + ci.chunk_length]
        records = StreamReader(io.BytesIO(raw), skip_magic=True).records
        try:
            for rec in records:
                n += isinstance(rec, Message)
        except EndOfFile:       # one chunk record, no footer after it
            pass
    return n


def test_bad_input_is_one_clear_error(tmp_path):
    with pytest.raises(LogError, match='no such MCAP file'):
        load_run(tmp_path / 'missing.mcap')
    (tmp_path / 'junk.mcap').write_bytes(b'not an mcap file at all')
    with pytest.raises(LogError, match='not an MCAP file'):
        load_run(tmp_path / 'junk.mcap')
    with pytest.raises(RecordingError, match='compression'):
        McapRecorder(tmp_path / 'x.mcap', compression='rar')
    (tmp_path / 'file').write_text('')
    with pytest.raises(RecordingError, match='cannot write MCAP file'):
        McapRecorder(tmp_path / 'file' / 'x.mcap')
    with McapRecorder(tmp_path / 'neg.mcap') as rec:
        with pytest.raises(RecordingError, match='negative stamp'):
            rec.write('/x', M.command_array([1.0], 'all'), -5)
        with pytest.raises(RecordingError, match='declare the topic'):
            rec.write_serialized('/y', b'\x00\x01\x00\x00', 0)
    assert rec.message_count == 0


def test_nothing_nan_is_logged(tmp_path):
    path = tmp_path / 'nan.mcap'
    topic = M.resolve_topic('~/cmd/impact')
    with McapRecorder(path) as rec:
        assert rec.write(topic, M.command_array([0.1], 'all'), 0)
        assert not rec.write(topic, M.command_array([float('nan')], 'all'), 1)
        assert not rec.write(topic, M.command_array([0.1, float('inf')], 'column'), 2)
        assert rec.write(topic, M.command_array([0.2], 'all'), 3)
    assert (rec.message_count, rec.dropped) == (2, 2)
    run = load_run(path)
    assert [v.tolist() for v in run.command_values] == [[0.1], [0.2]]


def test_replay_and_run_options_fail_with_one_line(log, tmp_path, capsys):
    from tensegrity_ros.cli import main
    assert main(['replay', str(tmp_path / 'none.mcap')]) == 2
    assert 'no such MCAP file' in capsys.readouterr().err
    for opt, value in (('--rate', '0'), ('--rate', 'nan'), ('--delay', '-1'), ('--wait', 'inf')):
        assert main(['replay', str(log[0]), opt, value]) == 2
        err = capsys.readouterr().err
        assert err.count('\n') == 1 and opt in err, err


def test_rerun_mcap_loader_reads_points_and_scalars(log, frames):
    """Rerun's own MCAP loader (rerun.chunk.McapReader, what `rerun file.mcap` and `rerun mcap
    convert` use) turns the PointCloud2 topic into Points3D and the arrays into Scalars."""
    chunk = pytest.importorskip('rerun.chunk')
    path, _ = log
    points, scalars = {}, {}
    for ch in chunk.McapReader(path, timeline_type='duration_ns').stream():
        if ch.is_static:
            continue
        rb = ch.to_record_batch()
        names = rb.schema.names
        t = rb.column('message_log_time').cast('int64').to_pylist()
        if ch.entity_path == M.resolve_topic('~/nodes') and 'Points3D:positions' in names:
            for ti, p in zip(t, rb.column('Points3D:positions').to_pylist()):
                points[ti] = np.array(p)
        if ch.entity_path == M.resolve_topic('~/strain') and 'Scalars:scalars' in names:
            for ti, s in zip(t, rb.column('Scalars:scalars').to_pylist()):
                scalars[ti] = np.array(s)
    assert sorted(points) == sorted(scalars) == [int(round(f.t * 1e9)) for f in frames]
    for f in frames:
        ns = int(round(f.t * 1e9))
        np.testing.assert_array_equal(points[ns], f.positions.astype(np.float32))
        np.testing.assert_array_equal(scalars[ns], f.strain.ravel())


def test_log_carries_its_network(log, net):
    got = load_run(log[0]).network
    for name in ('bar_a', 'bar_b', 'edge_a', 'edge_b', 'cable_a', 'cable_b', 'levels', 'x0'):
        np.testing.assert_array_equal(getattr(got, name), getattr(net, name), err_msg=name)
    assert list(got.cable_kind) == [str(k) for k in net.cable_kind]
    assert (got.n_nodes, got.n_cables, got.n_columns, got.n_prisms) == (
        net.n_nodes, net.n_cables, net.n_columns, net.n_prisms)
    assert got.tension_scale == style.reference_tension_scale(net)


def _rrd_columns(path, entity, column, index='sim_time'):
    """{time ns: value} of one component column of an .rrd file (rerun's own reader)."""
    from rerun.chunk import RrdReader
    out = {}
    for ch in RrdReader(path).stream():
        if ch.entity_path != entity or ch.is_static:
            continue
        rb = ch.to_record_batch()
        if column in rb.schema.names:
            assert 'log_time' not in rb.schema.names
            for ti, v in zip(rb.column(index).cast('int64').to_pylist(),
                             rb.column(column).to_pylist()):
                out[ti] = np.array(v)
    return out


def test_to_rerun_has_the_live_recording_layout(log, frames, tmp_path):
    """A log with its network converts through RerunRecorder: nodes, bars, cables, strain."""
    pytest.importorskip('rerun.chunk')
    from tensegrity_ros.io.convert import to_rerun
    path, written = log
    out = tmp_path / 'run.rrd'
    # nodes, strain, tension, base force and energy of each frame, and the command
    assert to_rerun(path, out) == 5 * len(frames) + 1
    stamps = [int(round(f.t * 1e9)) for f in frames]
    nodes = _rrd_columns(out, '/world/nodes', 'Points3D:positions')
    strain = _rrd_columns(out, '/strain/column_0', 'Scalars:scalars')
    assert sorted(nodes) == sorted(strain) == stamps
    for f, ns in zip(frames, stamps):
        np.testing.assert_array_equal(nodes[ns], f.positions.astype(np.float32))
        np.testing.assert_array_equal(strain[ns], f.strain[0])
    assert sorted(_rrd_columns(out, '/world/cables', 'LineStrips3D:strips')) == stamps


def test_to_rerun_without_network_converts_topic_by_topic(net, frames, tmp_path):
    chunk = pytest.importorskip('rerun.chunk')
    from tensegrity_ros.io.convert import to_rerun
    path = tmp_path / 'bare.mcap'
    written = record_frames(path, frames, net, marker_every=3, with_network=False)
    assert load_run(path).network is None
    out = tmp_path / 'run.rrd'
    assert to_rerun(path, out) == len([w for w in written if w[0] != '/clock'])
    nodes = {}
    for ch in chunk.RrdReader(out).stream():
        if ch.entity_path == '/nodes' and not ch.is_static:
            rb = ch.to_record_batch()
            assert 'log_time' not in rb.schema.names
            for ti, p in zip(rb.column('sim_time').cast('int64').to_pylist(),
                             rb.column('Points3D:positions').to_pylist()):
                nodes[ti] = np.array(p)
    assert sorted(nodes) == [int(round(f.t * 1e9)) for f in frames]
    np.testing.assert_array_equal(nodes[0], frames[0].positions.astype(np.float32))


def test_run_cli_logs_each_impact_of_a_train_and_the_balance_error(tmp_path, capsys):
    """``tensegrity run --mcap`` of a train of 3: a received ``cmd/impact`` at each impact's time,
    ``energy_balance_error`` in the headless ``/diagnostics``, and a series of it in the
    conversion to Rerun."""
    from pathlib import Path

    from tensegrity_ros.cli import main
    from tensegrity_ros.io.convert import to_rerun
    fb = Path(__file__).resolve().parents[1] / 'config' / 'scenes' / 'fb_column.yaml'
    assert main(['run', str(fb), '--set', 'structure.n_prisms=4', '--set',
                 'loading.impact.count=3', '--set', 'loading.impact.period=0.0075', '--t-end',
                 '0.02', '--out', str(tmp_path), '--mcap', '--json']) == 0
    out = json.loads(capsys.readouterr().out)
    log = McapLog(out['outputs']['mcap'])
    impacts, balance = [], []
    for m in log.messages():
        if m.topic.endswith('/cmd/impact'):
            impacts.append((m.log_time_ns, list(log.decode(m).data)))
        elif m.type_name == 'diagnostic_msgs/msg/DiagnosticArray':
            values = {kv.key: kv.value for kv in log.decode(m).status[0].values}
            balance.append(float(values['energy_balance_error']))
    assert impacts == [(0, [0.1]), (7_500_000, [0.1]), (15_000_000, [0.1])]
    assert balance and max(abs(b) for b in balance) < 1e-4
    assert 0 < out['energy_balance_error'] < 1e-4
    pytest.importorskip('rerun.chunk')
    to_rerun(out['outputs']['mcap'], tmp_path / 'run.rrd')
    assert _rrd_columns(tmp_path / 'run.rrd', '/energy_balance_error', 'Scalars:scalars')
