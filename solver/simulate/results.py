"""The typed results of a run: :class:`RunSummary` (what ``tensegrity run`` prints, a sweep row
and a fit read), the impacts a run applied (:class:`ImpactApplied`) and each striker at the end
(:class:`StrikerEnd`). Code reads their fields; :meth:`RunSummary.to_json` is the strict JSON of
docs/interfaces.md section 2, for files and other programs."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np


def json_safe(value):
    """``value`` (dicts, lists, numbers, strings) with every non-finite float replaced by None, so
    that it is strict JSON (``null``): a pulse not found in a short run has NaN figures, and JSON
    has no NaN."""
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


@dataclass(frozen=True)
class ImpactApplied:
    """One impact a run applied: at ``t_s`` s of simulation time, ``v0_m_s`` m/s, the work
    ``work_J`` J it did (the ledger books it)."""
    t_s: float
    v0_m_s: float
    work_J: float

    def as_dict(self):
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class StrikerEnd:
    """A striker at the end of a run (``loading.impact.mode: striker``): its face height ``z_m``
    m and axial velocity ``v_m_s`` m/s, > 0 away from the column."""
    z_m: float
    v_m_s: float


@dataclass(frozen=True)
class Outputs:
    """The files a run wrote (None: not written): the rosbag2 bag folder, the Rerun recording,
    the strain-wave plot."""
    mcap: str | None = None
    rerun: str | None = None
    plot: str | None = None


@dataclass(frozen=True)
class RunSummary:
    """The summary of one run (:func:`solver.simulate.runner.summary`). Times in s, energies in J,
    errors relative. ``pulses``: each column's :class:`~solver.analysis.observables.Pulse`
    (:attr:`pulse` the first); ``base``: each column's base-force figures (the JSON's ``base``
    entries: arrival figures, ``max_N``, ``min_N``; empty without a base-force record);
    ``striker``: each column's :class:`StrikerEnd`, None without strikers."""
    scene: str
    model: str
    integrator: str
    dt: float
    t_end: float
    n_nodes: int
    n_bars: int
    n_cables: int
    n_rigid_edges: int
    steps: int
    steps_taken: int
    wall_time_s: float
    real_time_factor: float
    energy_drift_rel: float
    constraint_error_rel: float
    impacts: tuple
    energy_work_J: float
    energy_balance_error: float
    bar_contact: str
    contacts_met: int
    pulses: tuple
    base: tuple
    striker: tuple | None
    outputs: Outputs = Outputs()

    @property
    def pulse(self):
        """The first column's :class:`~solver.analysis.observables.Pulse` (None: no column)."""
        return self.pulses[0] if self.pulses else None

    def with_outputs(self, **paths):
        """This summary with the given :class:`Outputs` paths set."""
        return dataclasses.replace(self, outputs=dataclasses.replace(self.outputs, **paths))

    def to_json(self):
        """The strict JSON object of docs/interfaces.md section 2 (non-finite figures None)."""
        out = {
            'scene': self.scene, 'model': self.model, 'integrator': self.integrator,
            'dt': self.dt, 't_end': self.t_end,
            'n_nodes': self.n_nodes, 'n_bars': self.n_bars, 'n_cables': self.n_cables,
            'n_rigid_edges': self.n_rigid_edges,
            'steps': self.steps, 'steps_taken': self.steps_taken,
            'wall_time_s': self.wall_time_s, 'real_time_factor': self.real_time_factor,
            'energy_drift_rel': self.energy_drift_rel,
            'constraint_error_rel': self.constraint_error_rel,
            'impacts': [i.as_dict() for i in self.impacts],
            'energy_work_J': self.energy_work_J,
            'energy_balance_error': self.energy_balance_error,
            'bar_contact': self.bar_contact, 'contacts_met': self.contacts_met,
            'pulse': self.pulse.as_dict() if self.pulse is not None else None,
            'pulses': [p.as_dict() for p in self.pulses],
            'base': [dict(b) for b in self.base],
            'striker': None if self.striker is None else [dataclasses.asdict(s)
                                                          for s in self.striker],
            'outputs': dataclasses.asdict(self.outputs),
        }
        return json_safe(out)
