"""The solver's public face: what users and ``tensegrity_ros`` import (``from solver import
Scene, simulate_scene``). Names load on first use (PEP 562), so importing one module of the
solver does not import all of it.

- scenes and networks: :class:`Scene`, :class:`SceneError`, :data:`RANGES`,
  :func:`build_network`, :class:`NetworkError`;
- one simulation: :class:`Simulation`, :func:`simulation_for`, :class:`SimulationDiverged`,
  :class:`Frame`;
- runs: :func:`simulate_scene` (:func:`solver.simulate.runner.simulate`),
  :func:`frame_count`, :func:`run_frame`, :class:`ImpactTrain`, :data:`T_REF`; their typed
  results :class:`RunSummary` and :func:`json_safe`;
- many runs: :func:`simulate_batch`, :func:`default_threads`, :func:`on_threads`
  (:func:`solver.simulate.parallel.each`: a function of each item on a pool of threads),
  :data:`MAX_LANES` (the most instances a lane group steps together); the
  convergence check
  (:mod:`solver.simulate.convergence`, as ``convergence``, and its names);
- studies and analysis modules: ``lens``, ``paper``, ``field``, ``observables``,
  ``lens_record``, ``front``; status codes: ``status``;
- the compiled kernels: :func:`compile_all`, :func:`source_hash`.
"""
import importlib

_NAMES = {
    'Scene': 'solver.build.scene', 'SceneError': 'solver.build.scene',
    'RANGES': 'solver.build.scene',
    'build_network': 'solver.build.structures', 'NetworkError': 'solver.build.network',
    'Simulation': 'solver.simulate.simulation', 'Frame': 'solver.simulate.simulation',
    'SimulationDiverged': 'solver.simulate.simulation',
    'simulation_for': 'solver.simulate.array',
    # solver.simulate is the sub-package: the run of a scene is simulate_scene
    'simulate_scene': 'solver.simulate.runner:simulate',
    'frame_count': 'solver.simulate.runner', 'run_frame': 'solver.simulate.runner',
    'ImpactTrain': 'solver.simulate.runner', 'T_REF': 'solver.simulate.runner',
    'json_safe': 'solver.simulate.results', 'RunSummary': 'solver.simulate.results',
    'simulate_batch': 'solver.simulate.batch', 'default_threads': 'solver.simulate.batch',
    'on_threads': 'solver.simulate.parallel:each', 'MAX_LANES': 'solver.simulate.lanebatch',
    'compile_all': 'solver.simulate.precompile', 'source_hash': 'solver.compiled',
    # the convergence check
    **{name: 'solver.simulate.convergence' for name in (
        'FIGURES', 'TOLERANCE', 'PERTURBATION', 'check_tolerance', 'check_figures', 'compare',
        'figures_of',
        'describe', 'refined_overrides', 'perturbed_overrides')},
    # the record of an array impact and the pulse front
    **{name: 'solver.studies.lens_record' for name in (
        'ImpactRecord', 'is_array', 'grid_extent', 'image_grid', 'IMAGE_SHAPE')},
    **{name: 'solver.analysis.front' for name in ('FRONT_LEVEL', 'front_arrivals',
                                                 'front_stations')},
}
_MODULES = {
    'convergence': 'solver.simulate.convergence', 'lens': 'solver.studies.lens',
    'paper': 'solver.studies.paper', 'field': 'solver.analysis.field',
    'observables': 'solver.analysis.observables', 'lens_record': 'solver.studies.lens_record',
    'front': 'solver.analysis.front', 'status': 'solver.status',
}
__all__ = sorted(_NAMES) + sorted(_MODULES)


def __getattr__(name):
    if name in _MODULES:
        value = importlib.import_module(_MODULES[name])
    elif name in _NAMES:
        module, _, attr = _NAMES[name].partition(':')
        value = getattr(importlib.import_module(module), attr or name)
    else:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    return value        # not kept here: a name patched in its module (a test) is seen


def __dir__():
    return __all__
