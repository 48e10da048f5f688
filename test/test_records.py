"""The solver's data model as code (docs/architecture.md, "The records"): the kernels work on
named records, never on numbered slots; integrators know no effect; no module reaches for
another's private names or probes an object for an interface; the model interface is an abstract
base the models implement. Each check is also shown to catch a violation written on purpose."""
from __future__ import annotations

import ast
import inspect
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
PRODUCT = ('solver', 'tensegrity_ros')

# Names the product gives to kernel records (and to the tuples they replaced): a subscript of one
# of them by an integer literal is a numbered slot read.
RECORD_NAMES = {'net', 'act', 'ws', 'ex', 'summ', 'keep', 'plan', 'extras', 'kws', 'kkt', 'rec',
                'data', 'work', 'topo', 'model', 'summary', 'contact', 'ledger', 'damping',
                'stops', 'strikers', 'bar_contact', 'spec', 'kept', 'trial', 'sm', 'bc', 'st'}
# effect sub-records of the model and data records: what an integrator kernel must not read
EFFECT_FIELDS = {'damping', 'stops', 'strikers', 'bar_contact', 'contact', 'ledger', 'refine',
                 'levels', 'summary'}
EFFECT_MODULES = {'solver.kernels.contact', 'solver.kernels.barcontact',
                  'solver.kernels.contactsteps'}
# getattr with a default / hasattr that do not stand in for an interface: on an argparse
# namespace (``args``: the options of whichever command shares a function) or an exception of a
# library (``exc``: PyYAML's errors carry ``problem`` only sometimes), and these (the reason
# beside each)
PROBE_OBJECTS_ALLOWED = {'args', 'exc'}
PROBES_ALLOWED = {
    ('solver/build/memo.py', 'hasattr(v, \'__array__\')'),         # any value of a memo key
    ('solver/simulate/parallel.py', 'getattr(_INSIDE, \'on\', False)'),   # threading.local
    ('tensegrity_ros/io/bag_format.py', 'getattr(d, \'nanoseconds\', 0)'),  # rclpy Duration
    ('tensegrity_ros/io/mcap_writer.py', 'getattr(msg, \'data\', None)'),   # ROS messages
    ('tensegrity_ros/io/mcap_writer.py', 'getattr(data, \'typecode\', \'\')'),
    ('tensegrity_ros/io/mcap_writer.py', 'hasattr(msg, \'layout\')'),
}


def product_files(root=ROOT):
    for pkg in PRODUCT:
        yield from sorted((root / pkg).rglob('*.py'))


def _name(node):
    """The last name of a Name or Attribute node, else None."""
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        return node.attr
    return None


def _int_literal(node):
    return (isinstance(node, ast.Constant) and isinstance(node.value, int)
            and not isinstance(node.value, bool))


def slot_reads(path):
    """``(line, source)`` of every subscript by an integer literal of a record name (a variable
    or attribute of that name: ``act[3]``, ``self.rec[0]``, and so ``act[3][8]`` too)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if (isinstance(node, ast.Subscript) and _int_literal(node.slice)
                and _name(node.value) in RECORD_NAMES):
            found.append((node.lineno, ast.unparse(node)))
    return sorted(found)


def test_no_kernel_record_is_read_by_a_numbered_slot():
    found = {str(p.relative_to(ROOT)): r for p in product_files() if (r := slot_reads(p))}
    assert not found, f'numbered slot reads of kernel records: {found}'


def test_the_slot_check_finds_a_slot_read_written_on_purpose(tmp_path):
    path = tmp_path / 'bad.py'
    path.write_text('def f(act, self):\n    a = act[3][8]\n    return self.rec[0] + a\n')
    assert slot_reads(path) == [(2, 'act[3]'), (3, 'self.rec[0]')]


def _jit_functions(tree):
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef) and any(
                _name(d) in ('jit', 'jit_inline') for d in node.decorator_list):
            yield node


def effect_reads(path):
    """What the ``@jit`` functions of an integrator module read of effects: attributes named as
    an effect sub-record, and imports of an effect module."""
    tree = ast.parse(path.read_text(), str(path))
    found = [f'import {n.module}' for n in ast.walk(tree)
             if isinstance(n, ast.ImportFrom) and n.module in EFFECT_MODULES]
    found += [f'import {a.name}' for n in ast.walk(tree) if isinstance(n, ast.Import)
              for a in n.names if a.name in EFFECT_MODULES]
    for fn in _jit_functions(tree):
        for node in ast.walk(fn):
            if isinstance(node, ast.Attribute) and node.attr in EFFECT_FIELDS:
                found.append(f'{fn.name}: {ast.unparse(node)}')
    return found


def test_integrator_kernels_know_no_effect():
    """The review rule of the integrators, as a check: their kernels reach the effects only
    through ``dynamics.accelerations`` and the entries of ``solver.kernels.effects``."""
    found = {p.name: r for p in sorted((ROOT / 'solver' / 'integrators').glob('*.py'))
             if (r := effect_reads(p))}
    assert not found, f'integrator kernels reading effects: {found}'


def test_the_effect_check_finds_a_branch_written_on_purpose(tmp_path):
    path = tmp_path / 'bad.py'
    path.write_text('from solver.kernels.contact import striker_step\n'
                    '@jit\ndef run(m, d):\n    if m.damping.coef.shape[0]:\n        return 1\n')
    found = effect_reads(path)
    assert 'import solver.kernels.contact' in found and 'run: m.damping' in found


def probes(path):
    """``getattr(obj, name, default)`` and ``hasattr`` calls not allowed above."""
    rel = str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else path.name
    found = []
    for n in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(n, ast.Call) and isinstance(n.func, ast.Name) and (
                n.func.id == 'hasattr' or (n.func.id == 'getattr' and len(n.args) == 3)):
            if (rel, ast.unparse(n)) not in PROBES_ALLOWED and not (
                    isinstance(n.args[0], ast.Name) and n.args[0].id in PROBE_OBJECTS_ALLOWED):
                found.append(ast.unparse(n))
    return found


def test_no_probe_stands_in_for_an_interface():
    found = {str(p.relative_to(ROOT)): r for p in product_files() if (r := probes(p))}
    assert not found, f'getattr/hasattr standing in for an interface: {found}'


def private_imports(path):
    """Imports of another module's underscore names (or of an underscore module) from the
    product."""
    found = []
    for n in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(n, ast.ImportFrom) and n.module and n.module.split('.')[0] in PRODUCT:
            parts = n.module.split('.')
            found += [f'{n.module} ({p})' for p in parts if p.startswith('_')
                      and not p.startswith('__')]
            found += [f'{n.module}.{a.name}' for a in n.names
                      if a.name.startswith('_') and not a.name.startswith('__')]
        elif isinstance(n, ast.Import):
            found += [a.name for a in n.names if a.name.split('.')[0] in PRODUCT
                      and any(p.startswith('_') and not p.startswith('__')
                              for p in a.name.split('.'))]
    return found


def test_no_module_imports_another_modules_private_names():
    found = {str(p.relative_to(ROOT)): r for p in product_files() if (r := private_imports(p))}
    assert not found, f'imports of private names: {found}'


def test_the_private_import_check_finds_one_written_on_purpose(tmp_path):
    path = tmp_path / 'bad.py'
    path.write_text('from solver.build.network import _ro\nfrom solver import _hidden\n')
    assert len(private_imports(path)) == 2


def test_tensegrity_ros_uses_the_solvers_public_face_only():
    """``tensegrity_ros`` imports from ``solver`` only the names ``solver/__init__.py`` exports."""
    import solver
    bad = []
    for path in sorted((ROOT / 'tensegrity_ros').rglob('*.py')):
        for n in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(n, ast.ImportFrom) and n.module and n.module.split('.')[0] == 'solver':
                if n.module != 'solver':
                    bad.append(f'{path.name}: from {n.module} import ...')
                else:
                    bad += [f'{path.name}: {a.name}' for a in n.names
                            if a.name not in solver.__all__]
            elif isinstance(n, ast.Import):
                bad += [f'{path.name}: import {a.name}' for a in n.names
                        if a.name.startswith('solver.')]
    assert not bad, bad


def test_records_are_named_and_the_model_record_is_read_only():
    """Every kernel record is a NamedTuple of named fields; every array of a built model record is
    read-only (built once, never edited), every array of its data writable."""
    from solver.kernels import records
    from solver.build.scene import Scene
    from solver.simulate.simulation import Simulation
    for cls in (records.Model, records.Data, records.Work, records.Topology,
                records.BarContact, records.Strikers, records.Stops, records.Damping,
                records.Summary, records.ContactState):
        assert issubclass(cls, tuple) and cls._fields
    scene = Scene.load(ROOT / 'config' / 'scenes' / 'fb_column.yaml').with_overrides(
        ['loading.impact.mode=striker', 'contact.lock=penalty',
         'materials.cable_damping_ratio=0.01'])
    m = Simulation(scene).model

    def arrays(value):
        if isinstance(value, tuple):
            for v in value:
                yield from arrays(v)
        elif isinstance(value, np.ndarray):
            yield value
    rec = list(arrays(m.rec))
    data = list(arrays(m.data))
    assert rec and not any(a.flags.writeable for a in rec)
    assert data and all(a.flags.writeable for a in data)
    assert m.rec.strikers.row.size == 1 and m.rec.stops.height.size and m.rec.damping.coef.size


def test_every_model_implements_the_abstract_interface():
    """``Full3D``, ``Sym3D`` and ``Chain1D`` implement every abstract method of
    :class:`solver.models.base.Model`; the array's model view implements its view."""
    from solver.models import base
    from solver.models.family import MODELS
    from solver.simulate.array import ArraySimulation
    for cls in MODELS.values():
        assert issubclass(cls, base.Model) and not inspect.isabstract(cls), cls
    view = ArraySimulation.__init__.__globals__['_ArrayModel']
    assert issubclass(view, base.ModelView) and not inspect.isabstract(view)

    class Half(base.RecordModel):           # a model that forgets part of the interface
        def positions(self):
            return None
    with pytest.raises(TypeError, match='abstract'):
        Half(None)


def test_both_simulations_implement_the_simulation_interface_and_nothing_more():
    """``Simulation`` and ``ArraySimulation`` implement every abstract member of
    :class:`solver.simulate.interface.SimulationAPI`; the array is not a ``Simulation`` (it
    inherits none of its code), and what runs, batches and the node call of a simulation is the
    interface's (the array answers all of it)."""
    from solver import Scene, Simulation, simulation_for
    from solver.simulate.array import ArraySimulation
    from solver.simulate.interface import SimulationAPI
    for cls in (Simulation, ArraySimulation):
        assert issubclass(cls, SimulationAPI) and not inspect.isabstract(cls), cls
    assert not issubclass(ArraySimulation, Simulation)
    array = simulation_for(Scene.load(ROOT / 'config' / 'scenes' / 'lens_array.yaml'))
    assert isinstance(array, ArraySimulation)
    nc, n_p = array.network.n_columns, array.network.n_prisms
    array.apply_prestrain([0.01 * (c + 1) for c in range(nc)], ramp_s=0.01)
    assert array.prestrain_goal.shape == (nc, n_p) and array.striker() is None
    assert array.prestrain_map.cross_prism is not None
    array.apply_impact(0.1)
    array.advance(0.02)
    assert np.allclose(array.prestrain, array.prestrain_goal)   # the ramp is done

    class Half(SimulationAPI):              # a simulation that forgets part of the interface
        def reset(self):
            pass
    with pytest.raises(TypeError, match='abstract'):
        Half()


def test_the_run_summary_is_a_typed_record_whose_json_is_the_cli_s(capsys):
    """``simulate`` returns a frozen :class:`RunSummary` whose fields carry the figures (impacts
    and pulses as records), and ``tensegrity run --json`` prints its :meth:`to_json` (the same
    run again: equal but for the timings)."""
    import dataclasses
    import json
    from solver import RunSummary, simulate_scene
    from solver.analysis.observables import Pulse
    from solver.simulate.results import ImpactApplied
    from tensegrity_ros import cli
    scene = str(ROOT / 'config' / 'scenes' / 'fb_column.yaml')
    sets = [('loading.impact.v0', 0.1), ('run.t_end', 0.3)]
    s = simulate_scene(scene, sets).summary
    assert isinstance(s, RunSummary)
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.steps = 0
    assert [type(i) for i in s.impacts] == [ImpactApplied] and s.impacts[0].v0_m_s == 0.1
    assert isinstance(s.pulse, Pulse) and s.pulse is s.pulses[0]
    assert s.steps == round(0.3 / s.dt) and s.steps_taken >= s.steps
    assert s.with_outputs(plot='p.png').outputs.plot == 'p.png' and s.outputs.plot is None
    capsys.readouterr()
    assert cli.main(['run', scene, '--v0', '0.1', '--t-end', '0.3', '--json']) == 0
    printed = json.loads(capsys.readouterr().out)
    own = s.to_json()
    timing = ('wall_time_s', 'real_time_factor')
    assert {k: v for k, v in printed.items() if k not in timing} == \
        {k: v for k, v in own.items() if k not in timing}
    assert printed['pulse']['amplitude_median'] == s.pulse.amplitude_median > 0.0
