"""The recorders the node's parameters ask for (``record_mcap``, ``record_rerun``), as sinks
(:mod:`tensegrity_ros.io.sinks`)."""
from __future__ import annotations

from tensegrity_ros.io.sinks import McapSink, RerunSink
from tensegrity_ros.msgs import messages
from tensegrity_ros.node.qos import QOS


def open_recorders(params, sim, topics, pubs, tension_scale):
    """The sinks of ``params``' recorders for ``sim``: an MCAP bag declaring every topic of
    ``topics`` (key -> full name) with the QoS of its publisher in ``pubs`` (the default for one
    not created: ``/clock`` may be switched on later), and a Rerun recording."""
    sinks = []
    if params['record_mcap']:
        from tensegrity_ros.io.mcap_frames import network_metadata
        from tensegrity_ros.io.mcap_writer import McapRecorder
        rec = McapRecorder(params['record_mcap'], bag=True,
                           metadata=network_metadata(sim.network, sim.scene.name))
        for key, topic in topics.items():
            pub = pubs.get(key)
            rec.declare(topic, messages.MSG_CLASSES[key],
                        pub.qos_profile if pub is not None else QOS)
        sinks.append(McapSink(rec))
    if params['record_rerun']:
        from solver import grid_extent, image_grid, is_array
        from tensegrity_ros.io.rerun_sink import RerunRecorder
        grid = grid_extent(*image_grid(sim.scene)) if is_array(sim.scene) else None
        sinks.append(RerunSink(RerunRecorder(sim.network, params['record_rerun'],
                                             tension_scale=tension_scale, field_grid=grid)))
    return sinks
