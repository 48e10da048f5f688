"""bench.flops's count of the floating-point operations of one force-and-constraint evaluation,
checked by an independent method: the kernels' own Python source (``py_func`` of every numba
kernel the evaluation calls), rewritten so that every ``+ - * /`` whose result is a float and
every ``math.sqrt`` goes through a counter, executed in Python on the same data. The counting
twin must give the accelerations of the compiled kernel bit for bit (it runs the same
operations in the same order) and the count :func:`bench.flops.count` derives from the
network's arrays, part by part; the lane kernel's twin must do the executed count in each lane.
"""
from __future__ import annotations

import ast
import copy
import inspect
import math
import textwrap

import numpy as np
import pytest

from bench import flops
from solver.kernels import dynamics as dyn
from solver.kernels import lanes, records
from solver.status import OK

OPS = {ast.Add: ('add', lambda a, b: a + b), ast.Sub: ('add', lambda a, b: a - b),
       ast.Mult: ('mul', lambda a, b: a * b), ast.Div: ('div', lambda a, b: a / b)}


class Counter:
    """Counts by part: the function called by the top one (each call its own entry, in order),
    or the top function itself for the operations written in it."""

    def __init__(self):
        self.stack = []
        self.calls = []

    def enter(self, name):
        self.stack.append(name)
        if len(self.stack) <= 2:
            self.calls.append([name, dict.fromkeys(flops.KINDS, 0)])

    def leave(self):
        self.stack.pop()
        if len(self.stack) == 1:        # back in the top function: its own operations
            self.calls.append([self.stack[0], dict.fromkeys(flops.KINDS, 0)])

    def add(self, kind):
        self.calls[-1][1][kind] += 1

    def op(self, kind, result):
        if isinstance(result, float):   # np.float64 too; index arithmetic is int
            self.add(kind)
        return result

    def parts(self):
        """``{name: counts}`` summed over the calls of one name; a second call of a name (the
        second ``apply_w``) as ``name_2``."""
        out = {}
        for name, c in self.calls:
            if not any(c.values()):
                continue
            key = name if name not in out else f'{name}_2'
            out[key] = c
        return out


class _Rewrite(ast.NodeTransformer):
    def visit_BinOp(self, node):
        self.generic_visit(node)
        if type(node.op) not in OPS:
            return node
        name = type(node.op).__name__
        return ast.Call(ast.Name('__count_op', ast.Load()),
                        [ast.Constant(name), node.left, node.right], [])

    def visit_AugAssign(self, node):
        self.generic_visit(node)
        if type(node.op) not in OPS:
            return node
        load = copy.deepcopy(node.target)
        for n in ast.walk(load):
            if hasattr(n, 'ctx'):
                n.ctx = ast.Load()
        value = ast.Call(ast.Name('__count_op', ast.Load()),
                         [ast.Constant(type(node.op).__name__), load, node.value], [])
        return ast.Assign([node.target], value)


class _Math:
    """``math`` with a counted ``sqrt``."""

    def __init__(self, counter):
        self._counter = counter

    def sqrt(self, x):
        self._counter.add('sqrt')
        return math.sqrt(x)

    def __getattr__(self, name):
        return getattr(math, name)


def twin(kernel, counter, memo=None):
    """The counting twin of a numba kernel (or plain function): its source rewritten, its
    globals the kernel module's with every kernel it calls replaced by that kernel's twin (made
    on first call) and ``math`` by :class:`_Math`."""
    memo = {} if memo is None else memo
    py = getattr(kernel, 'py_func', kernel)
    if py in memo:
        return memo[py]
    tree = ast.parse(textwrap.dedent(inspect.getsource(py)))
    tree.body[0].decorator_list = []
    tree = ast.fix_missing_locations(_Rewrite().visit(tree))
    env = dict(py.__globals__)
    ops = {type(k()).__name__: v for k, v in OPS.items()}
    env['__count_op'] = lambda name, a, b: counter.op(ops[name][0], ops[name][1](a, b))
    for name in py.__code__.co_names:
        value = env.get(name)
        if value is math:
            env[name] = _Math(counter)
        elif hasattr(value, 'py_func'):
            env[name] = _lazy(value, counter, memo)
    exec(compile(tree, inspect.getsourcefile(py), 'exec'), env)
    inner = env[py.__name__]

    def run(*args):
        counter.enter(py.__name__)
        try:
            return inner(*args)
        finally:
            counter.leave()
    memo[py] = run
    return run


def _lazy(kernel, counter, memo):
    def call(*args):
        return twin(kernel, counter, memo)(*args)
    return call


def _column(name, x_noise=0.0):
    net = flops.network() if name == 'FB' else _rb()
    m, d, w = records.plain(net)
    rng = np.random.default_rng(11)
    d.x[...] += x_noise * rng.normal(size=d.x.shape)
    d.v[...] = 0.01 * rng.normal(size=d.v.shape)
    assert dyn.project_velocities(d.x, d.v, m.topo, w) == OK
    return net, m, d, w


def _rb():
    from bench.common import COLUMNS
    from solver.build import structures
    from solver.build.scene import Scene
    scene = Scene.load(COLUMNS['RB']).with_overrides([('model', 'full3d'),
                                                      ('contact.bars', 'none')])
    return structures.build_network(scene)


def _counted(m, d, w):
    counter = Counter()
    out = np.zeros_like(d.x)
    ww = records.clone_work(w)
    assert twin(dyn.accelerations, counter)(d.x, d.v, m, d, ww, out) == OK
    return counter, out


@pytest.mark.parametrize('name, noise', [('FB', 0.0), ('FB', 3e-4), ('RB', 3e-4)])
def test_count_equals_the_kernels_source_counted(name, noise):
    """FB at rest (every cable taut), FB with positions shaken so that some cables are slack,
    RB (a constraint band of width 7: the general LDL^T, not the tridiagonal form)."""
    net, m, d, w = _column(name, noise)
    counter, out = _counted(m, d, w)
    expected = np.zeros_like(d.x)
    assert dyn.accelerations(d.x, d.v, m, d, records.clone_work(w), expected) == OK
    assert np.array_equal(out, expected)            # the twin ran the kernel's operations
    parts, taut = flops.count(m, d, source=True)
    if noise:
        assert 0 < taut < net.n_cables
    else:
        assert taut == net.n_cables
    got = counter.parts()
    got['rhs'] = got.pop('accelerations')           # the loop written in accelerations itself
    got['constraint_forces'] = got.pop('_add_forces')
    got.pop('copy_into', None)                      # no arithmetic: not listed
    assert set(got) == set(flops.PARTS)
    for part in flops.PARTS:
        want = {k: parts[part][k] for k in flops.KINDS}
        assert got[part] == want, part


def test_each_lane_does_the_executed_count():
    """The lane kernel (every cable taut) performs, per lane, :func:`bench.flops.count`'s
    executed count: ``g * d`` once per axis, as LLVM compiles the scalar source."""
    net = flops.network()
    m, d, _ = flops.scalar_state(net)
    n_lanes = 3
    data, work = flops.lane_state(net, n_lanes, d.v)
    counter = Counter()
    status = np.zeros(n_lanes, np.int64)
    twin(lanes.accelerations, counter)(data.x, data.v, net.topology(), data, work,
                                       np.zeros_like(data.x), status)
    assert list(status) == [OK] * n_lanes
    total = dict.fromkeys(flops.KINDS, 0)
    for _, c in counter.calls:
        for k in flops.KINDS:
            total[k] += c[k]
    parts, taut = flops.count(m, d)
    assert taut == net.n_cables
    assert flops.lanes_count(net, n_lanes) == n_lanes * parts['total']['total']
    assert total == {k: n_lanes * parts['total'][k] for k in flops.KINDS}


def test_peak_arithmetic():
    p = flops.peak(3.0, {'avx2', 'avx512f', 'fma'})
    assert p['peak_gflops_widest'] == 3.0 * 8 * 2 * flops.FMA_UNITS
    assert p['peak_gflops_256bit'] == 3.0 * 4 * 2 * flops.FMA_UNITS
    assert p['peak_gflops_scalar'] == 3.0 * 2 * flops.FMA_UNITS
    assert flops.peak(3.0, {'avx2', 'fma'})['peak_gflops_widest'] == p['peak_gflops_256bit']


def test_llvm_computes_each_cable_force_product_once():
    """The executed count of a taut cable (22, :func:`bench.flops.cable_ops`) is what LLVM
    compiles the scalar ``cable_forces`` into: its IR (one loop body, fresh compile without the
    cache) holds 12 fadd/fsub, 7 fmul (``g * d`` once per axis, not the source's twice), 2 fdiv,
    1 sqrt, and no FMA."""
    import re

    import numba
    kernel = numba.njit(_nrt=False)(dyn.cable_forces.py_func)
    x = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    ab = np.array([0]), np.array([1])
    kernel(x, *ab, np.array([0.5]), np.array([1.0]), np.zeros_like(x))
    (ir,) = kernel.inspect_llvm().values()
    found = {op: len(re.findall(rf'= {op} ', ir)) for op in ('fadd', 'fsub', 'fmul', 'fdiv')}
    want = flops.cable_ops(1, 1)
    assert found['fadd'] + found['fsub'] == want['add']
    assert found['fmul'] == want['mul']
    assert found['fdiv'] == want['div']
    assert len(re.findall(r'call .*@llvm\.sqrt', ir)) == want['sqrt']
    assert 'llvm.fma' not in ir and 'fmuladd' not in ir
