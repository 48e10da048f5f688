"""A log of ``n`` frames written the way ``tensegrity run --mcap`` writes one (with its network,
synthetic frames, no simulation)."""
from mcap_helpers import small_network, synthetic_frames


def record_long(path, n, n_prisms=3, chunk_size=4096):
    from tensegrity_ros.io.mcap_frames import FrameLog, network_metadata
    from tensegrity_ros.io.mcap_writer import McapRecorder
    net = small_network(n_prisms)
    with McapRecorder(path, chunk_size=chunk_size,
                      metadata=network_metadata(net, 'synthetic')) as rec:
        log = FrameLog(rec, net, marker_every=10)
        for f in synthetic_frames(net, n, dt=0.005):
            log.frame(f)
    return net
