"""The points of a sweep: ``--grid`` axes (values, ``START:STOP:N`` or ranges for Latin-hypercube
``--samples``), their cartesian product or samples, and the key of each point (a hash of the scene,
the overrides and the solver's source), so that a resumed sweep knows what it has run."""
from __future__ import annotations

import functools
import hashlib
import itertools
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml


class SweepError(ValueError):
    """Bad sweep or fit input; the message names the option or key."""


@dataclass
class Axis:
    """One swept key: its ``values`` (a list) or a ``range`` (start, stop) for Latin-hypercube
    samples."""
    key: str
    values: list | None = None
    range: tuple | None = None
    text: str = ''


def _scalar(text, what):
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:
        raise SweepError(f'{what}: cannot parse value {text!r}') from None


def _number(text, what):
    value = _scalar(text, what)
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            pass
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SweepError(f'{what}: {text!r} is not a finite number')
    return value


def parse_axis(text, option='--grid'):
    """``KEY=V1,V2,...`` (values), ``KEY=START:STOP:N`` (N evenly spaced values, both ends
    included) or ``KEY=START:STOP`` (a range for ``--samples``)."""
    if '=' not in text:
        raise SweepError(f'{option} {text!r}: expected KEY=V1,V2,... or KEY=START:STOP:N')
    key, spec = (s.strip() for s in text.split('=', 1))
    if not key or not spec:
        raise SweepError(f'{option} {text!r}: expected KEY=V1,V2,... or KEY=START:STOP:N')
    what = f'{option} {key}'
    if ':' in spec:
        parts = spec.split(':')
        if len(parts) not in (2, 3):
            raise SweepError(f'{what}: expected START:STOP:N or START:STOP, got {spec!r}')
        lo, hi = _number(parts[0], what), _number(parts[1], what)
        if not hi > lo:
            raise SweepError(f'{what}: STOP ({parts[1]}) must be greater than START ({parts[0]})')
        if len(parts) == 2:
            return Axis(key, range=(float(lo), float(hi)), text=text)
        n = _number(parts[2], what)
        if not (isinstance(n, int) or float(n).is_integer()) or n < 1:
            raise SweepError(f'{what}: N must be a whole number >= 1, got {parts[2]!r}')
        values = [float(v) for v in np.linspace(lo, hi, int(n))] if n > 1 else [float(lo)]
        return Axis(key, values=values, text=text)
    values = [_scalar(v.strip(), what) for v in spec.split(',')]
    if any(v is None or v == '' for v in values):
        raise SweepError(f'{what}: empty value in {spec!r}')
    if len(set(map(repr, values))) != len(values):
        raise SweepError(f'{what}: repeated value in {spec!r}')
    return Axis(key, values=values, text=text)


def points(axes, samples=None, seed=0):
    """The points of a sweep: a list of dicts ``{key: value}`` in the order of ``axes``.

    Without ``samples``: the cartesian product of every axis's values. With ``samples``: that
    many Latin-hypercube points (:class:`scipy.stats.qmc.LatinHypercube`, seeded) over the axes
    given as ranges, crossed with the values of the others."""
    keys = [a.key for a in axes]
    if len(set(keys)) != len(keys):
        dup = next(k for k in keys if keys.count(k) > 1)
        raise SweepError(f'--grid {dup}: given twice')
    if samples is None:
        ranged = [a for a in axes if a.range is not None]
        if ranged:
            raise SweepError(f'--grid {ranged[0].key}: START:STOP needs a count (START:STOP:N) '
                             'or --samples N')
        return [dict(zip(keys, combo)) for combo in itertools.product(*[a.values for a in axes])]
    if samples < 1:
        raise SweepError(f'--samples: must be >= 1, got {samples}')
    ranged = [a for a in axes if a.range is not None]
    if not ranged:
        raise SweepError('--samples: needs at least one --grid KEY=START:STOP range')
    from scipy.stats import qmc
    unit = qmc.LatinHypercube(d=len(ranged), rng=np.random.default_rng(seed)).random(samples)
    lo = np.array([a.range[0] for a in ranged])
    hi = np.array([a.range[1] for a in ranged])
    drawn = qmc.scale(unit, lo, hi)
    listed = [a for a in axes if a.range is None]
    out = []
    for combo in itertools.product(*[a.values for a in listed]):
        fixed = dict(zip([a.key for a in listed], combo))
        for row in drawn:
            sampled = {a.key: float(v) for a, v in zip(ranged, row)}
            out.append({k: (fixed[k] if k in fixed else sampled[k]) for k in keys})
    return out


def canonical(value):
    """A value as a plain JSON type (numpy scalars to Python)."""
    if isinstance(value, np.generic):
        return value.item()
    return value


@functools.lru_cache(maxsize=1)
def code_version():
    """A hash of the solver's source (every ``solver/**/*.py``): a resumed sweep reruns its points
    after the solver changed instead of mixing rows of two versions."""
    import solver
    return source_hash(Path(solver.__file__).parent)


def source_hash(directory):
    """sha256 (12 hex digits) of every ``*.py`` file below ``directory`` (sub-packages too)."""
    from solver import source_hash as solver_hash
    return solver_hash(directory)[:12]


def point_id(scene_data, overrides, code=None):
    """A key of the point: a hash of the scene's validated data, the overrides in canonical
    form (sorted keys, JSON) and the solver's :func:`code_version`, so that the same point gets
    the same key in any order of options, and a new key when the solver changes."""
    blob = json.dumps({'scene': scene_data, 'code': code or code_version(),
                       'set': sorted([k, canonical(v)] for k, v in overrides.items())},
                      sort_keys=True, default=repr)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]
