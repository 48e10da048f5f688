"""What tests of the node share: :func:`commanded_node` starts the node in its own rclpy context
beside a :class:`~tensegrity_ros.node.demo.Commander`; :class:`Logged` records what the node does
to its simulation, so that a test can replay it on another and compare what the node published."""
import contextlib


@contextlib.contextmanager
def commanded_node(domain_id, scene_file, prepare=None, connect_s=60, **parameters):
    """``(node, executor, commander, log)``: the node on ``scene_file`` (``real_time_factor`` 0
    and 200 Hz publishing unless ``parameters`` say otherwise) in a context of its own on
    ``domain_id``, its simulation's calls recorded (:class:`Logged`; ``prepare(node)`` runs
    before), a commander connected to it within ``connect_s`` s (to a node started paused:
    ``Commander.connected(paused=True)``); all torn down on exit."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from tensegrity_ros.node.demo import Commander, spin_until
    from tensegrity_ros.node.node import TensegritySim
    values = {'scene_file': str(scene_file), 'real_time_factor': 0.0, 'publish_rate_hz': 200.0,
              **parameters}
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain_id)
    node = TensegritySim(context=ctx, parameter_overrides=[
        Parameter(k, value=v) for k, v in values.items()])
    if prepare is not None:
        prepare(node)
    log = Logged(node.sim)
    cmd = Commander(context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    ex.add_node(cmd)
    try:
        paused = bool(values.get('start_paused', False))
        assert spin_until(ex, lambda: cmd.connected(paused=paused), connect_s), \
            'commander never connected'
        yield node, ex, cmd, log
    finally:
        ex.shutdown()
        node.close()
        cmd.destroy_node()
        node.destroy_node()
        rclpy.shutdown(context=ctx)


class Logged:
    """What the node does to its simulation, in order: each call of the recorded methods with
    its arguments (the replay repeats them on another simulation). A recorded method that calls
    another one (``advance_part`` taking a whole step through ``advance``) is recorded once, as
    the node called it."""

    METHODS = ('advance', 'advance_part', 'apply_prestrain', 'apply_impact', 'reset')

    def __init__(self, sim):
        self.calls = []
        self.depth = 0
        for name in self.METHODS:
            setattr(sim, name, self._wrap(name, getattr(sim, name)))

    def _wrap(self, name, method):
        def call(*args, **kwargs):
            if self.depth == 0:
                self.calls.append((name, args, kwargs))
            self.depth += 1
            try:
                return method(*args, **kwargs)
            finally:
                self.depth -= 1
        return call

    def replay(self, sim):
        for name, args, kwargs in self.calls:
            getattr(sim, name)(*args, **kwargs)
