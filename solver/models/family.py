"""The model family: a scene pays only for the model it needs.

Every model implements :class:`solver.models.base.Model`: its state as full (n_nodes, 3) arrays
(``positions()``, ``velocities()``, ``set_state``), its cables (``cable_rest_length``,
``cable_EA``, ``set_cables``), ``keep``/``restore`` of what the steps change, ``copy``. ``full3d``
(:mod:`solver.models.full3d`) and ``sym3d`` (:mod:`solver.models.sym3d`) are
:class:`~solver.models.base.RecordModel` models, stepped by an integrator on their records
(:mod:`solver.kernels.records`); ``chain1d`` (:mod:`solver.models.chain1d`) integrates itself.

``sym3d`` raises :class:`~solver.models.sym3d.NotSymmetric` from ``set_state`` or ``set_cables``
when given an asymmetric state; the simulation then expands the run to ``full3d``
(:func:`expand`).

To add a model: implement :class:`~solver.models.base.Model` (or a
:class:`~solver.models.base.RecordModel` built by :func:`solver.models.extras.build`), add it to
:data:`MODELS`, and teach :func:`choose` when ``model: auto`` may pick it (only when it is exact
for the scene).
"""
from __future__ import annotations

from solver.models.chain1d import Chain1D
from solver.models.full3d import Full3D, full_summary_arrays  # noqa: F401 (the family's face)
from solver.models.sym3d import NotSymmetric, Sym3D, reduce_network

MODELS = {cls.name: cls for cls in (Full3D, Sym3D, Chain1D)}


def symmetric_loading(scene):
    """Whether the scene's loading keeps the 3-fold symmetry about z: gravity acts along z and
    every impact is axial on a whole level (always true for the loads a scene can describe);
    returns (bool, reason)."""
    return True, 'axial impact on whole levels, gravity along z'


def choose(requested, network, scene):
    """The model class for a scene. ``auto`` picks the cheapest exact model: ``sym3d`` when the
    network is 3-fold symmetric about z (structure, materials, supports) and the loading is too,
    ``full3d`` otherwise. ``chain1d`` is an approximation and is used only when asked for."""
    if requested == 'auto':
        ok, _ = symmetric_loading(scene)
        if ok:
            try:
                reduce_network(network)
                return Sym3D
            except NotSymmetric:
                pass
        return Full3D
    if requested not in MODELS:
        raise ValueError(f'model {requested!r} is not available; available: '
                         f'{", ".join(sorted(MODELS))}')
    if requested == 'sym3d':
        try:
            reduce_network(network)
        except NotSymmetric as exc:
            raise ValueError(f'model sym3d: {exc}') from None
    return MODELS[requested]


def expand(model, f_ext=None, striker_state=None):
    """A :class:`Full3D` model holding the state and cables of ``model`` (no jump: the full state
    is the symmetric expansion of the reduced one), with its effects and the strikers at
    ``striker_state``."""
    full = Full3D(model.network, f_ext=f_ext, effects=model.effects, striker_state=striker_state)
    full.set_state(model.positions(), model.velocities())
    full.set_cables(model.cable_rest_length, model.cable_EA)
    return full
