"""The sections of a validated scene as typed, frozen records: ``scene.run.t_end``,
``scene.loading.impact.v0``, ``scene.structure.n_columns``.

The code reads a scene through these records (a misspelled field is an ``AttributeError`` at
once, and editors and type checkers see the fields); dotted keys (``scene['run.t_end']``) stay
for what users write: scene files and ``--set KEY=VALUE``. Each record has exactly the keys of
its section in :data:`solver.build.scene.DEFAULTS` (tested); lists become tuples.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ColumnStructure:
    builder: str
    n_prisms: int
    n_columns: int
    column_spacing: float
    radius: float
    h0: float
    bases: str
    stacking: str
    rigid_bases_as: str
    kappa: float
    clamped_levels: tuple
    handedness: str
    mass_placement: str


@dataclass(frozen=True)
class ExplicitStructure:
    builder: str
    nodes: tuple
    bars: tuple
    cables: tuple
    rigid_edges: tuple
    clamped: tuple
    node_mass: float
    cable_rest_length: tuple | None


@dataclass(frozen=True)
class Materials:
    cable_E: float
    cable_radius: float
    unit_mass: float
    bar_mass: float
    bar_mass_fraction: float
    end_mass: float
    cable_damping: float
    cable_damping_ratio: float
    bar_radius: float
    bar_E: float
    bar_poisson: float


@dataclass(frozen=True)
class Impact:
    v0: float
    mode: str
    columns: tuple | None
    striker_mass: float
    contact: str
    contact_stiffness: float
    period: float
    count: int
    times: tuple | None
    velocities: tuple | None

    def train(self):
        """The impacts ``((t s, v0 m/s), ...)`` in time order: ``count`` of ``v0`` every
        ``period`` s from t = 0, or one at each of ``times`` (of ``velocities``, or all ``v0``)."""
        if self.times is None:
            return tuple((k * self.period, self.v0) for k in range(self.count))
        return tuple(zip(self.times, self.velocities or (self.v0,) * len(self.times)))


@dataclass(frozen=True)
class Loading:
    impact: Impact
    gravity: float


@dataclass(frozen=True)
class Integrator:
    method: str
    dt: float
    projection_tol: float
    projection_max_iter: int
    land_on_kinks: bool
    rtol: float
    atol: float
    lanes: str


@dataclass(frozen=True)
class Run:
    t_end: float
    output_dt: float


@dataclass(frozen=True)
class Contact:
    bars: str
    resolution: int
    lock: str
    stiffness: float
    tolerance: float
    refine: str


@dataclass(frozen=True)
class Divergence:
    energy_error: float
    constraint_error: float
    bar_crossing: str


@dataclass(frozen=True)
class Outputs:
    dir: str | None


@dataclass(frozen=True)
class Lens:
    prestrain_min: float
    prestrain_max: float
    grid: int


SECTIONS = {'materials': Materials, 'integrator': Integrator, 'run': Run, 'contact': Contact,
            'divergence': Divergence, 'outputs': Outputs, 'lens': Lens}
STRUCTURES = {'column': ColumnStructure, 'explicit': ExplicitStructure}


def frozen(value):
    """Lists as tuples, all the way down (a record's values cannot be changed in place)."""
    if isinstance(value, list):
        return tuple(frozen(v) for v in value)
    return value


def record(name, data):
    """The record of section ``name`` of validated scene data ``data`` (the section's dict)."""
    if name == 'structure':
        cls = STRUCTURES[data['builder']]
    elif name == 'loading':
        return Loading(impact=Impact(**{k: frozen(v) for k, v in data['impact'].items()}),
                       gravity=data['gravity'])
    else:
        cls = SECTIONS[name]
    return cls(**{k: frozen(v) for k, v in data.items()})
