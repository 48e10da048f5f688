"""One interface for everything that records a run, the node's and ``tensegrity run``'s alike:
MCAP logs, Rerun recordings, test probes.

A sink is a :class:`Sink`: it takes some of these calls (the attributes it sets to a callable;
the others stay None and are not called):

- ``message(topic, msg, stamp_ns)``: a published or received message, full topic name; with
  ``takes_bytes = True`` a frame's messages come as the CDR bytes that were published;
- ``frame(frame)``: a published :class:`solver.simulate.simulation.Frame`;
- ``event(t, text)``: a command or event at simulation time ``t`` s;
- ``impact(index, entry)``: impact ``index`` of a headless run's train, applied (``entry``: its
  :class:`solver.simulate.results.ImpactApplied`);
- ``field(t, peak, pressure)``: the field maps of an array in its host medium;
- ``close()``: at shutdown.

:class:`FanOut` hands each call to every sink that takes it; a sink that raises is dropped
(and reported), so a broken recorder never stops the simulation.
"""
from __future__ import annotations

KINDS = ('message', 'frame', 'event', 'impact', 'field', 'close')


class Sink:
    """A recorder's calls (:data:`KINDS`): ``Sink(frame=f, close=c)``, or a subclass that sets
    them; ``takes_bytes``: messages as CDR bytes."""
    message = frame = event = impact = field = close = None
    takes_bytes = False

    def __init__(self, takes_bytes=None, **calls):
        unknown = set(calls) - set(KINDS)
        if unknown:
            raise TypeError(f'Sink: unknown calls {sorted(unknown)}; a sink takes {KINDS}')
        for kind, fn in calls.items():
            setattr(self, kind, fn)
        if takes_bytes is not None:
            self.takes_bytes = bool(takes_bytes)


class FanOut:
    """The sinks of a node or a run. ``on_error(sink, exc)`` is told of a sink that failed. The
    sinks of each kind are listed once when a sink is added or dropped (a frame's messages pass
    here several hundred times a second)."""

    def __init__(self, on_error=None):
        self.on_error = on_error
        self.sinks = []
        self._index()

    def _index(self):
        self._by_kind = {kind: tuple((s, getattr(s, kind)) for s in self.sinks
                                     if getattr(s, kind) is not None) for kind in KINDS}
        self.wants_objects = any(not s.takes_bytes for s, _ in self._by_kind['message'])

    def add(self, sink):
        if not isinstance(sink, Sink):
            raise TypeError(f'a sink is a tensegrity_ros.io.sinks.Sink, not {type(sink).__name__}')
        self.sinks.append(sink)
        self._index()
        return sink

    def has(self, kind):
        """Whether any sink takes ``kind`` (one of :data:`KINDS`)."""
        return bool(self._by_kind[kind])

    def _call(self, kind, *args):
        for sink, fn in self._by_kind[kind]:
            try:
                fn(*args)
            except Exception as exc:    # a broken recorder must not stop the simulation
                self._drop(sink, exc)

    def _drop(self, sink, exc):
        if sink in self.sinks:
            self.sinks.remove(sink)
            self._index()
        if self.on_error is not None:
            self.on_error(sink, exc)

    def message(self, topic, msg, stamp_ns):
        self._call('message', topic, msg, stamp_ns)

    def frame(self, frame):
        self._call('frame', frame)

    def event(self, t, text):
        self._call('event', t, text)

    def impact(self, index, entry):
        self._call('impact', index, entry)

    def field(self, t, peak, pressure):
        self._call('field', t, peak, pressure)

    def close(self):
        """Close every sink once (each in turn, whatever the others do); the list is emptied."""
        closers = self._by_kind['close']
        self.sinks = []
        self._index()
        for sink, fn in closers:
            try:
                fn()
            except Exception as exc:
                if self.on_error is not None:
                    self.on_error(sink, exc)


class McapSink(Sink):
    """An :class:`~tensegrity_ros.io.mcap_writer.McapRecorder` as a sink (it takes CDR bytes)."""
    takes_bytes = True

    def __init__(self, recorder):
        self.message, self.close = recorder.write, recorder.close


class RerunSink(Sink):
    """A :class:`~tensegrity_ros.io.rerun_sink.RerunRecorder` as a sink (frames, events and, when
    it has a field grid, the field maps)."""

    def __init__(self, recorder):
        self.frame, self.event, self.close = recorder.frame, recorder.command, recorder.close
        if recorder.field_grid is not None:
            self.field = recorder.field
