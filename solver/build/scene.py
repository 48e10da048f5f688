"""Scene files: YAML -> validated, frozen :class:`Scene` (SI units; unknown keys are errors).

Every default lives in :data:`DEFAULTS`; the type of a default is the type a value must have. A
scene file gives only what differs. ``--set KEY=VALUE`` overrides use dotted keys
(``integrator.dt=2e-4``); ``integrator=NAME`` is short for ``integrator.method=NAME``, and picks
the method as a user does: with its own step where the scene's is too large for it, refused where
it cannot run the scene (:data:`METHOD_STEPS`, :data:`METHOD_REFUSALS`).
"""
from __future__ import annotations

import copy
import math
from pathlib import Path

import yaml

from solver.build import sections


class SceneError(ValueError):
    """A scene file or override that cannot be used; the message names the key."""


COLUMN_DEFAULTS = {
    'builder': 'column',
    'n_prisms': 50,
    'n_columns': 1,
    'column_spacing': 0.03,
    'radius': 0.005,
    'h0': 0.0062,
    'bases': 'flexible',
    'stacking': 'shared',
    'rigid_bases_as': 'edges',
    'kappa': 100.0,
    'clamped_levels': [0],
    'handedness': 'right',
    'mass_placement': 'level',
}
EXPLICIT_DEFAULTS = {
    'builder': 'explicit',
    'nodes': [],
    'bars': [],
    'cables': [],
    'rigid_edges': [],
    'clamped': [],
    'node_mass': 0.0083,
    'cable_rest_length': None,
}
STRUCTURE_DEFAULTS = {'column': COLUMN_DEFAULTS, 'explicit': EXPLICIT_DEFAULTS}

DEFAULTS = {
    'name': 'scene',
    'description': '',
    'structure': COLUMN_DEFAULTS,
    'materials': {'cable_E': 5.48e6, 'cable_radius': 1.4e-4, 'unit_mass': 0.0249, 'bar_mass': 0.0,
                  'bar_mass_fraction': 0.0, 'end_mass': 0.0, 'cable_damping': 0.0,
                  'cable_damping_ratio': 0.0,
                  # bars as steel rods 0.2 mm thick (what touches in a prism: docs/physics.md)
                  'bar_radius': 1.0e-4, 'bar_E': 2.0e11, 'bar_poisson': 0.3},
    'prestrain': 0.002,
    'loading': {'impact': {'v0': 0.1, 'mode': 'impulse', 'columns': None,
                           'striker_mass': 0.0249, 'contact': 'linear',
                           'contact_stiffness': 1.0e4,
                           # a train: count impacts every period s from t = 0, or one impact at
                           # each of times s (velocities m/s, null: every one v0)
                           'period': 0.0, 'count': 1, 'times': None, 'velocities': None},
                'gravity': 0.0},
    'model': 'auto',
    'integrator': {'method': 'rk4_projected', 'dt': 5e-4, 'projection_tol': 1e-12,
                   'projection_max_iter': 3, 'land_on_kinks': True, 'rtol': 1e-8, 'atol': 1e-10,
                   # the distinct columns of an array stepped together as lanes
                   # (solver.simulate.lanebatch; the same results): off, on, or auto (the
                   # faster as measured along the run)
                   'lanes': 'off'},
    'run': {'t_end': 1.2, 'output_dt': 0.005},
    'contact': {'bars': 'hertz', 'resolution': 40, 'lock': 'none', 'stiffness': 1.0e5,
                'tolerance': 0.05,
                # after a contact, rk4's steps checked against the energy ledger and halved
                # where they use more than their share (solver.integrators.rk4); none: never
                'refine': 'ledger'},
    'divergence': {'energy_error': 1e-4, 'constraint_error': 1e-6, 'bar_crossing': 'rigid'},
    'outputs': {'dir': None},
    # the focusing design (solver/studies/lens.py): the prestrain range it may use, the grid of
    # its map
    'lens': {'prestrain_min': 0.003, 'prestrain_max': 0.015, 'grid': 13},
}

CHOICES = {
    'structure.builder': ('column', 'explicit'),
    'structure.bases': ('flexible', 'rigid'),
    'structure.stacking': ('shared', 'parallel'),
    'structure.rigid_bases_as': ('edges', 'stiff_cables'),
    'structure.handedness': ('right', 'left'),
    # where the lumped part of each prism's mass sits: one unit per level, or half on each base
    'structure.mass_placement': ('level', 'unit_bases'),
    'loading.impact.mode': ('impulse', 'energy', 'striker'),
    'loading.impact.contact': ('linear', 'hertz'),
    # a penalty stop between the two levels of each prism, at the rigid-base lock (flexible
    # bases: where the bases meet) plus contact.tolerance * h0
    'contact.lock': ('none', 'penalty'),
    # the bars of each prism touch with their thickness: Hertz contact of crossed rods, or not
    'contact.bars': ('hertz', 'none'),
    'contact.refine': ('ledger', 'none'),
    'model': ('auto', 'full3d', 'sym3d', 'chain1d'),
    'integrator.lanes': ('off', 'on', 'auto'),
    # stop when a prism twists through 180 deg (its bars cross): in rigid-base columns only (the
    # lock), in every column, or never
    'divergence.bar_crossing': ('rigid', 'all', 'none'),
}

# (lower, upper, lower inclusive) for numbers
RANGES = {
    'structure.n_prisms': (1, 10000, True),
    'structure.n_columns': (1, 1000, True),
    'structure.column_spacing': (0.0, math.inf, False),
    'structure.radius': (0.0, math.inf, False),
    'structure.h0': (0.0, math.inf, False),
    'structure.kappa': (0.0, math.inf, False),
    'structure.node_mass': (0.0, math.inf, False),
    'materials.cable_E': (0.0, math.inf, False),
    'materials.cable_radius': (0.0, math.inf, False),
    'materials.unit_mass': (0.0, math.inf, False),
    'materials.bar_mass': (0.0, math.inf, True),
    'materials.end_mass': (0.0, math.inf, True),
    'materials.cable_damping': (0.0, math.inf, True),
    'materials.cable_damping_ratio': (0.0, 100.0, True),
    'loading.impact.striker_mass': (0.0, math.inf, False),
    'loading.impact.contact_stiffness': (0.0, math.inf, False),
    'contact.stiffness': (0.0, math.inf, False),
    'contact.resolution': (4, 100000, True),
    'materials.bar_radius': (0.0, math.inf, False),
    'materials.bar_E': (0.0, math.inf, False),
    'materials.bar_poisson': (0.0, 0.5, True),
    'contact.tolerance': (0.0, 1.0, False),
    'prestrain': (0.0, 0.5, False),
    'loading.impact.v0': (-10.0, 10.0, True),
    'loading.impact.period': (0.0, 1e6, True),
    'loading.impact.count': (1, 1000000, True),
    'integrator.dt': (0.0, 0.1, False),
    'integrator.projection_tol': (0.0, 1e-3, False),
    'integrator.projection_max_iter': (1, 100, True),
    'integrator.rtol': (0.0, 0.1, False),      # adaptive methods only (dopri54_projected)
    'integrator.atol': (0.0, 1.0, False),
    'run.t_end': (0.0, 1e6, True),
    'run.output_dt': (0.0, 1e3, False),
    'lens.prestrain_min': (0.0, 0.5, False),
    'lens.prestrain_max': (0.0, 0.5, False),
    'lens.grid': (3, 200, True),
    'divergence.energy_error': (0.0, math.inf, False),
    'divergence.constraint_error': (0.0, math.inf, False),
}

SHORTCUTS = {'integrator': 'integrator.method'}

# What ``integrator=NAME`` does beyond ``integrator.method=NAME`` (docs/integrators.md, "Methods
# on the default columns"; test/test_method_matrix.py runs the matrix). The largest step of a
# method where the scenes' steps are too large for it: the shorthand lowers a larger
# integrator.dt to it, unless the same overrides set integrator.dt. rk4 (no projection) at the
# scenes' own steps drifts past divergence.constraint_error at 1 m/s (fb_column at t = 0.85 s,
# rb_column at 0.06 s); at 1.25e-4 s it runs both columns at 0.1 and 1 m/s to 1.2 s.
METHOD_STEPS = {'rk4': 1.25e-4}
# Methods the shorthand refuses, with the condition on the scene's data and the reason. rattle's
# fixed steps cannot follow the bars' Hertz contact of a strong impact: at 1 m/s it diverges at
# about 7 ms on both default columns, where the struck prisms are crushed until their bars
# touch, even at an eighth of their steps (with line bars those prisms collapse at 8 ms).
METHOD_REFUSALS = {
    'rattle': (lambda data: data['contact']['bars'] != 'none',
               'its fixed steps cannot follow the bars\' Hertz contact (contact.bars: hertz) of '
               'a strong impact; use integrator=rk4_projected or integrator=dopri54_projected'),
}


def _type_name(value):
    if isinstance(value, bool):
        return 'a boolean'
    if isinstance(value, int):
        return 'an integer'
    if isinstance(value, float):
        return 'a number'
    if isinstance(value, str):
        return 'a string'
    if isinstance(value, list):
        return 'a list'
    return type(value).__name__


def _check_value(key, default, value):
    if default is None:           # free-form (optional lists or numbers)
        return value
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise SceneError(f'{key}: expected true or false, got {value!r}')
        return value
    if isinstance(default, (int, float)) and not isinstance(default, bool):
        if isinstance(value, str):      # YAML 1.1 reads 5.48e6 (no dot) as a string
            try:
                value = float(value)
            except ValueError:
                pass
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise SceneError(f'{key}: expected {_type_name(default)}, got {value!r}')
        if isinstance(default, int) and not isinstance(value, int):
            if float(value).is_integer():
                value = int(value)
            else:
                raise SceneError(f'{key}: expected an integer, got {value!r}')
        if not math.isfinite(value):
            raise SceneError(f'{key}: must be finite, got {value!r}')
        if isinstance(default, float):
            value = float(value)
        if key in RANGES:
            lo, hi, inclusive = RANGES[key]
            if value > hi or value < lo or (value == lo and not inclusive):
                bracket = '[' if inclusive else '('
                raise SceneError(f'{key}: {value!r} is outside {bracket}{lo}, {hi}]')
        return value
    if isinstance(default, str):
        if not isinstance(value, str):
            raise SceneError(f'{key}: expected a string, got {value!r}')
        if key in CHOICES and value not in CHOICES[key]:
            raise SceneError(f'{key}: {value!r} is not one of {", ".join(CHOICES[key])}')
        return value
    if isinstance(default, list):
        if not isinstance(value, list):
            raise SceneError(f'{key}: expected a list, got {value!r}')
        return value
    return value


def _unknown(key, node):
    """The message for an unknown (dotted) key, listing the valid keys at its level as a scene
    file's unknown key does."""
    if not isinstance(node, dict):
        return f'{key}: unknown key ({key.rsplit(".", 1)[0]} has no sub-keys)'
    return f'{key}: unknown key (valid here: {", ".join(sorted(node))})'


def _merge(defaults, given, prefix=''):
    if not isinstance(given, dict):
        raise SceneError(f'{prefix.rstrip(".") or "scene"}: expected a mapping, got {given!r}')
    out = {}
    for key in given:
        if key not in defaults:
            full = prefix + str(key)
            valid = ', '.join(sorted(defaults))
            raise SceneError(f'{full}: unknown key (valid here: {valid})')
    for key, default in defaults.items():
        full = prefix + key
        if isinstance(default, dict):
            out[key] = _merge(default, given.get(key, {}) if given.get(key) is not None else {},
                              full + '.')
        elif key in given:
            out[key] = _check_value(full, default, given[key])
        else:
            out[key] = copy.deepcopy(default)
    return out


def _numbers(key, values, what):
    """``values`` (a list from the scene) as floats: each a finite number (YAML 1.1 reads 5e-2,
    without a dot, as a string), else a SceneError."""
    if not isinstance(values, list) or not values:
        raise SceneError(f'{key}: expected a non-empty list of {what} (or null), got {values!r}')
    out = []
    for v in values:
        try:
            x = float(v) if isinstance(v, (str, int, float)) and not isinstance(v, bool) else None
        except ValueError:
            x = None
        if x is None or not math.isfinite(x):
            raise SceneError(f'{key}: {v!r} is not a finite number ({what})')
        out.append(x)
    return out


def _check_train(imp, t_end):
    """Check the train keys of ``loading.impact`` (``imp``, merged) against ``run.t_end``; the
    times and velocities become lists of floats."""
    slack = t_end * (1.0 + 1e-9) + 1e-12           # (count - 1) * period rounds up at times
    times, velocities = imp['times'], imp['velocities']
    if times is None:
        if velocities is not None:
            raise SceneError('loading.impact.velocities: needs loading.impact.times (one velocity '
                             'per time)')
        count, period = imp['count'], imp['period']
        if count > 1 and not period > 0:
            raise SceneError(f'loading.impact.period: must be > 0 for loading.impact.count = '
                             f'{count} impacts')
        if (count - 1) * period > slack:
            raise SceneError(f'loading.impact.period: the last of {count} impacts every '
                             f'{period:g} s is at {(count - 1) * period:g} s, after run.t_end = '
                             f'{t_end:g} s')
        return
    if imp['count'] != 1 or imp['period'] != 0.0:
        raise SceneError('loading.impact.times: give either loading.impact.times or '
                         'loading.impact.period and count, not both')
    times = imp['times'] = _numbers('loading.impact.times', times, 'times in s')
    bad = [t for t in times if not 0.0 <= t <= slack]
    if bad:
        raise SceneError(f'loading.impact.times: {bad[0]:g} s is outside [0, run.t_end = '
                         f'{t_end:g} s]')
    if any(b < a for a, b in zip(times, times[1:])):
        raise SceneError(f'loading.impact.times: must be sorted, earliest first, got {times!r}')
    if velocities is not None:
        velocities = imp['velocities'] = _numbers('loading.impact.velocities', velocities,
                                                  'velocities in m/s')
        if len(velocities) != len(times):
            raise SceneError(f'loading.impact.velocities: {len(velocities)} given for '
                             f'{len(times)} loading.impact.times (one per time)')
        lo, hi, _ = RANGES['loading.impact.v0']
        bad = [v for v in velocities if not lo <= v <= hi]
        if bad:
            raise SceneError(f'loading.impact.velocities: {bad[0]:g} is outside [{lo}, {hi}]')


def validate(raw):
    """Merge a raw mapping onto the defaults and check every key; returns a plain nested dict."""
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        raise SceneError(f'scene: expected a mapping at the top level, got {type(raw).__name__}')
    structure = raw.get('structure') or {}
    if not isinstance(structure, dict):
        raise SceneError(f'structure: expected a mapping, got {structure!r}')
    builder = structure.get('builder', 'column')
    if builder not in STRUCTURE_DEFAULTS:
        raise SceneError(f'structure.builder: {builder!r} is not one of '
                         f'{", ".join(STRUCTURE_DEFAULTS)}')
    defaults = dict(DEFAULTS, structure=STRUCTURE_DEFAULTS[builder])
    data = _merge(defaults, raw)
    imp = data['loading']['impact']
    cols = imp['columns']
    if cols is not None:
        n_col = data['structure'].get('n_columns', 1)
        if not isinstance(cols, list) or not all(isinstance(c, int) and 0 <= c < n_col
                                                 for c in cols):
            raise SceneError(f'loading.impact.columns: expected a list of column indices '
                             f'0..{n_col - 1} or null, got {cols!r}')
    _check_train(imp, data['run']['t_end'])
    mat = data['materials']
    if not 0.0 <= mat['bar_mass_fraction'] < 1.0:     # [0, 1): RANGES has no open upper end
        raise SceneError(f'materials.bar_mass_fraction: {mat["bar_mass_fraction"]!r} is outside '
                         '[0.0, 1.0)')
    if builder != 'column':
        for key in ('bar_mass_fraction', 'end_mass'):
            if mat[key] != 0.0:
                raise SceneError(f'materials.{key}: only for structure.builder column (give '
                                 'node_mass and materials.bar_mass instead)')
    if mat['cable_damping'] > 0 and mat['cable_damping_ratio'] > 0:
        raise SceneError('materials.cable_damping_ratio: give either materials.cable_damping '
                         '(N s/m) or materials.cable_damping_ratio, not both')
    if data['run']['output_dt'] < data['integrator']['dt']:
        raise SceneError('run.output_dt: must not be smaller than integrator.dt')
    return data


class Scene:
    """A validated scene. The code reads its typed sections (:mod:`solver.build.sections`):
    ``scene.run.t_end``, ``scene.loading.impact.v0``, ``scene.structure``, ``scene.prestrain``;
    ``scene['run.t_end']`` (dotted keys, as users write them) and ``scene.data`` (a copy of the
    nested dict) serve overrides and files."""

    def __init__(self, data, source=None):
        self._data = validate(data)
        self.source = source
        for name in ('structure', 'materials', 'loading', 'integrator', 'run', 'contact',
                     'divergence', 'outputs', 'lens'):
            setattr(self, name, sections.record(name, self._data[name]))
        self.prestrain, self.model = self._data['prestrain'], self._data['model']

    @classmethod
    def load(cls, path):
        path = Path(path)
        try:
            text = path.read_text()
        except OSError as exc:
            raise SceneError(f'{path}: cannot read scene file ({exc.strerror})') from None
        try:
            raw = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            mark = getattr(exc, 'problem_mark', None)
            where = f' line {mark.line + 1}' if mark is not None else ''
            raise SceneError(f'{path}:{where} not valid YAML ({getattr(exc, "problem", exc)})') \
                from None
        if raw is None:                         # nothing but blanks or comments
            raise SceneError(f'{path}: the scene file is empty (give at least a name and a '
                             f'structure; see config/scenes/)')
        try:
            return cls(raw, source=str(path))
        except SceneError as exc:
            raise SceneError(f'{path}: {exc}') from None

    @property
    def data(self):
        return copy.deepcopy(self._data)

    def __getitem__(self, dotted):
        node = self._data
        for part in dotted.split('.'):
            node = node[part]
        return copy.deepcopy(node)

    @property
    def name(self):
        return self._data['name']

    def with_overrides(self, assignments):
        """A new scene with ``KEY=VALUE`` strings (or (key, value) pairs) applied; values are
        parsed as YAML scalars."""
        data = self.data
        picked, step_given = None, False
        for item in assignments:
            if isinstance(item, str):
                if '=' not in item:
                    raise SceneError(f'--set {item!r}: expected KEY=VALUE')
                key, text = item.split('=', 1)
                try:
                    value = yaml.safe_load(text)
                except yaml.YAMLError:
                    raise SceneError(f'--set {key}: cannot parse value {text!r}') from None
            else:
                key, value = item
            key = key.strip()
            if key in SHORTCUTS and not isinstance(value, dict):
                key, picked = SHORTCUTS[key], value
            step_given = step_given or key == 'integrator.dt'
            parts = key.split('.')
            node = data
            for part in parts[:-1]:
                if not isinstance(node, dict) or part not in node:
                    raise SceneError(_unknown(key, node))
                node = node[part]
            if not isinstance(node, dict) or parts[-1] not in node:
                raise SceneError(_unknown(key, node))
            node[parts[-1]] = value
        if picked is not None:
            _picked_method(data, picked, step_given)
        return Scene(data, source=self.source)


def _picked_method(data, name, step_given):
    """What ``integrator=NAME`` adds to ``integrator.method=NAME`` (in place on ``data``): the
    method's own step (:data:`METHOD_STEPS`) unless ``step_given``; a refusal
    (:data:`METHOD_REFUSALS`) where the scene is one the method cannot run."""
    refusal = METHOD_REFUSALS.get(name)
    if refusal is not None and isinstance(data.get('contact'), dict) and refusal[0](data):
        raise SceneError(f'integrator={name}: refused on this scene: {refusal[1]}')
    step = METHOD_STEPS.get(name)
    if step is not None and not step_given and isinstance(data.get('integrator'), dict):
        dt = data['integrator'].get('dt')
        if isinstance(dt, (int, float)) and dt > step:
            data['integrator']['dt'] = step
