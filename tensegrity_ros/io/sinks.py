"""One interface for everything that records a run: MCAP logs, Rerun recordings, test probes.

A sink is any object with some of these methods (the others are simply not called):

- ``message(topic, msg, stamp_ns)``: a published or received message, full topic name; with
  ``takes_bytes = True`` a frame's messages come as the CDR bytes that were published;
- ``frame(frame)``: a published :class:`solver.simulate.simulation.Frame`;
- ``event(t, text)``: a command or event at simulation time ``t`` s;
- ``field(t, peak, pressure)``: the field maps of an array in its host medium;
- ``close()``: at shutdown.

:class:`FanOut` hands each call to every sink that has the method; a sink that raises is dropped
(and reported), so a broken recorder never stops the simulation.
"""
from __future__ import annotations

KINDS = ('message', 'frame', 'event', 'field', 'close')


class FanOut:
    """The sinks of a node or a run. ``on_error(sink, exc)`` is told of a sink that failed."""

    def __init__(self, on_error=None):
        self.on_error = on_error
        self.sinks = []

    def add(self, sink):
        self.sinks.append(sink)
        return sink

    def has(self, kind):
        """Whether any sink takes ``kind`` (one of :data:`KINDS`)."""
        return any(callable(getattr(s, kind, None)) for s in self.sinks)

    @property
    def wants_objects(self):
        """Whether a sink takes messages as objects (not CDR bytes)."""
        return any(callable(getattr(s, 'message', None)) and not getattr(s, 'takes_bytes', False)
                   for s in self.sinks)

    def _call(self, kind, *args):
        for sink in list(self.sinks):
            fn = getattr(sink, kind, None)
            if not callable(fn):
                continue
            try:
                fn(*args)
            except Exception as exc:    # a broken recorder must not stop the simulation
                self.sinks.remove(sink)
                if self.on_error is not None:
                    self.on_error(sink, exc)

    def message(self, topic, msg, stamp_ns):
        self._call('message', topic, msg, stamp_ns)

    def frame(self, frame):
        self._call('frame', frame)

    def event(self, t, text):
        self._call('event', t, text)

    def field(self, t, peak, pressure):
        self._call('field', t, peak, pressure)

    def close(self):
        """Close every sink once (each in turn, whatever the others do); the list is emptied."""
        sinks, self.sinks = self.sinks, []
        for sink in sinks:
            fn = getattr(sink, 'close', None)
            if callable(fn):
                try:
                    fn()
                except Exception as exc:
                    if self.on_error is not None:
                        self.on_error(sink, exc)


class McapSink:
    """An :class:`~tensegrity_ros.io.mcap_writer.McapRecorder` as a sink (it takes CDR bytes)."""
    takes_bytes = True

    def __init__(self, recorder):
        self.message, self.close = recorder.write, recorder.close


class RerunSink:
    """A :class:`~tensegrity_ros.io.rerun_sink.RerunRecorder` as a sink (frames, events and, when
    it has a field grid, the field maps)."""

    def __init__(self, recorder):
        self.frame, self.event, self.close = recorder.frame, recorder.command, recorder.close
        if recorder.field_grid is not None:
            self.field = recorder.field
