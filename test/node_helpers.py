"""What tests of the node share: :class:`Logged` records what the node does to its simulation,
so that a test can replay it on another and compare what the node published."""


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
