"""The achieved GFLOP/s of one force-and-constraint evaluation of the FB column, scalar and per
lane, against this core's peak.

    python -m bench.flops [--out bench/results]

The network is the paper's FB column as a ``full3d`` network without bar contact (153 nodes, 303
cables, 150 bars in three chains: a tridiagonal constraint band), the state of
:mod:`bench.lanes` (at rest, an impact on the top level). The floating-point operations of one
:func:`solver.kernels.dynamics.accelerations` are counted by :func:`count` from the network's
arrays and state, loop by loop as the kernels do them: an add, a subtraction, a multiplication,
a division and a square root count 1 each; comparisons, sign flips and copies count 0. A cable
counts 9 (its length) when it is slack and 22 when taut (its force: ``g * dx`` is written twice
in the source and computed once, as LLVM and the lane kernel do it); :func:`count` also gives the
source's count (``test/test_flops.py`` checks both against the kernels' own source executed with
counters). The time of one evaluation is the best of :data:`REPEATS` loops of calls inside one
compiled function, scalar (:func:`solver.kernels.dynamics.accelerations`) and for B = 8, 32, 64,
128 lanes (:func:`solver.kernels.lanes.accelerations`, lane l with rest lengths scaled by
1 - 1e-5 l: every cable of every lane taut, so every lane does the scalar count).

GFLOP/s = flops / time (per lane: flops x B / batch time). The peak of one core is
GHz x doubles per instruction x 2 (an FMA is 2 flops) x FMA units: the clock is measured (a
chain of dependent 1-cycle integer operations, shift and xor), the vector width and FMA from
``/proc/cpuinfo`` flags (``avx512f``: 8 doubles, ``avx2``: 4, ``fma``), and :data:`FMA_UNITS`
is an assumption (two on Intel's server cores with AVX-512, Skylake-SP to Sapphire Rapids).
numba's code keeps to 256-bit vectors and, compiled without ``fastmath``, forms no FMA: the
256-bit peak, and half of it without FMA, are given too. One run's figures: on a busy machine
the times are noisy.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time
from pathlib import Path

import numpy as np

from solver.build import structures
from solver.build.scene import Scene
from solver.compiled import jit, jit_lanes
from solver.kernels import dynamics as dyn
from solver.kernels import lanes, records

from .common import COLUMNS

LANES = (8, 32, 64, 128)
REPEATS = 7
SECONDS = 0.05          # the length of one timed loop
FMA_UNITS = 2           # FMA units per core (assumed, see the module docstring)
CHAIN = 20_000_000      # iterations of the clock's dependency chain (2 cycles each)
PARTS = ('cable_forces', 'apply_w', 'member_vectors', 'rhs', 'assemble_band', 'band_ldl_solve',
         'constraint_forces', 'apply_w_2')
KINDS = ('add', 'mul', 'div', 'sqrt')      # 'add' counts subtractions too


# -- counting ---------------------------------------------------------------------------------
def _ops(add=0, mul=0, div=0, sqrt=0):
    return {'add': int(add), 'mul': int(mul), 'div': int(div), 'sqrt': int(sqrt)}


def taut_cables(x, cable_a, cable_b, rest):
    """How many cables are taut (``s > L``) at ``x``, with the kernel's arithmetic for ``s``."""
    dv = x[cable_b] - x[cable_a]
    s = np.sqrt(dv[:, 0] * dv[:, 0] + dv[:, 1] * dv[:, 1] + dv[:, 2] * dv[:, 2])
    return int((s > rest).sum())


def cable_ops(n_cables, n_taut, source=False):
    """Every cable: dx, dy, dz (3), ``dx dx + dy dy + dz dz`` (3 mul, 2 add) and its sqrt; a taut
    one also ``EA / L * (s - L) / s`` (2 div, 1 sub, 1 mul) and its force on both nodes (3 mul
    ``g * d``, 6 add; the source writes ``g * d`` twice: 6 mul with ``source``)."""
    return _ops(add=5 * n_cables + 7 * n_taut, mul=3 * n_cables + (7 if source else 4) * n_taut,
                div=2 * n_taut, sqrt=n_cables)


def apply_w_ops(partner):
    """``out = w f`` (3 mul a node) and, for a node with a partner (massive bars), ``+= wo f_q``
    (3 mul, 3 add)."""
    pairs = int((np.asarray(partner) >= 0).sum())
    return _ops(add=3 * pairs, mul=3 * len(partner) + 3 * pairs)


def band_ops(coef):
    """``band[c, k] = cf * (b_c . b_{c-k})`` (4 mul, 2 add) for the entries whose ``cf`` is
    nonzero and ``k <= c``; the others are set to 0."""
    c, k = np.nonzero(coef)
    n = int((k <= c).sum())
    return _ops(add=2 * n, mul=4 * n)


def ldl_ops(m, width):
    """The banded LDL^T factor and solve of :mod:`solver.kernels.banded` for ``m`` rows of band
    ``width`` (bandwidth ``bw = width - 1``), every band entry (zero or not) as the code does it.
    Factor, row i with ``r = min(i, bw)`` entries left of the diagonal: ``r (r - 1) / 2`` updates
    ``s -= L d`` (1 mul, 1 sub), r scalings ``l = w d_j`` and ``d -= w l`` (2 mul, 1 sub), one
    ``1 / d``; forward solve r ``s -= L y`` (1 mul, 1 sub); backward one ``y d`` and
    ``min(m - 1 - i, bw)`` ``s -= L y``. The bandwidth-1 form (``_tridiag_ldl_solve``) performs
    the same operations."""
    bw = width - 1
    i = np.arange(m)
    r = np.minimum(i, bw)
    u = np.minimum(m - 1 - i, bw)
    upd = int((r * (r - 1) // 2).sum())
    left = int(r.sum())
    right = int(u.sum())
    return _ops(add=upd + left + left + right, mul=upd + 2 * left + left + m + right, div=m)


def _check_plain(m):
    topo = m.topo
    if (topo.con_rot.shape[0] or topo.cable_rot.shape[0] or topo.kkt.node_u.shape[0]
            or m.damping.coef.shape[0] or m.stops.height.shape[0] or m.strikers.row.shape[0]
            or m.bar_contact.pairs.shape[0]):
        raise ValueError('flops: only a plain model with every effect off is counted')


def count(m, d, source=False):
    """Floating-point operations of one :func:`solver.kernels.dynamics.accelerations` of the
    plain model ``m`` (every effect off, as :func:`solver.kernels.records.plain` builds it) at the
    state of its data ``d``: ``{part: {'add', 'mul', 'div', 'sqrt', 'total'}}`` for the parts of
    :data:`PARTS` and ``'total'``, and the number of taut cables. ``source``: ``g * d`` of a taut
    cable counted twice, as the source writes it."""
    _check_plain(m)
    topo = m.topo
    n_con = topo.con_tail.shape[0]
    taut = taut_cables(d.x, topo.cable_a, topo.cable_b, d.rest)
    parts = {
        'cable_forces': cable_ops(topo.cable_a.shape[0], taut, source),
        'apply_w': apply_w_ops(topo.partner),
        'member_vectors': _ops(add=3 * n_con),
        # -(sum_i b_i (wf_h - wf_t)_i + dv_i dv_i), s starting at 0.0: 3 x (2 sub, 2 mul, 2 add)
        'rhs': _ops(add=12 * n_con, mul=6 * n_con),
        'assemble_band': band_ops(topo.con_coef),
        'band_ldl_solve': ldl_ops(*topo.con_coef.shape),
        'constraint_forces': _ops(add=6 * n_con, mul=3 * n_con),   # g = lam b_i; f_h +=, f_t -=
        'apply_w_2': apply_w_ops(topo.partner),
    }
    total = {k: sum(p[k] for p in parts.values()) for k in KINDS}
    parts['total'] = total
    for p in parts.values():
        p['total'] = sum(p[k] for k in KINDS)
    return parts, taut


# -- the machine ------------------------------------------------------------------------------
@jit
def _chain(x, n):
    """n iterations of ``x ^= x >> 7``: a dependent shift and xor, 1 cycle each on every x86
    core, so 2 cycles an iteration (the loop counter runs beside it)."""
    for _ in range(n):
        x ^= x >> 7
    return x


@jit
def _add_chain(s, n):
    """n dependent float additions (the latency of one addition each)."""
    for _ in range(n):
        s = s + 1e-300
    return s


@jit
def _divide(a, b, out, n):
    """n passes of ``out = a / b``: with the default error model (the scalar kernels') each
    division is one scalar ``vdivsd`` behind a zero check."""
    for _ in range(n):
        for i in range(a.shape[0]):
            out[i] = a[i] / b[i]


@jit_lanes
def _divide_vector(a, b, out, n):
    """:func:`_divide` under the lanes' error model: 256-bit ``vdivpd``."""
    for _ in range(n):
        for i in range(a.shape[0]):
            out[i] = a[i] / b[i]


@jit_lanes
def _sqrt_vector(a, out, n):
    """n passes of ``out = sqrt(a)``: 256-bit ``vsqrtpd``."""
    for _ in range(n):
        for i in range(a.shape[0]):
            out[i] = math.sqrt(a[i])


def _best(call, repeats=REPEATS):
    best = float('inf')
    for _ in range(repeats):
        t0 = time.perf_counter()
        call()
        best = min(best, time.perf_counter() - t0)
    return best


def cpuinfo():
    """The first core's fields of ``/proc/cpuinfo`` (``{}`` when absent)."""
    info = {}
    try:
        text = Path('/proc/cpuinfo').read_text()
    except OSError:
        return info
    for line in text.splitlines():
        if not line.strip():
            break
        key, _, value = line.partition(':')
        info.setdefault(key.strip(), value.strip())
    return info


def clock_ghz():
    """(GHz measured by :func:`_chain`, cycles a float addition takes at that clock)."""
    _chain(1, 10)
    _add_chain(0.0, 10)
    t = _best(lambda: _chain(12345, CHAIN))
    ghz = 2 * CHAIN / t / 1e9
    t_add = _best(lambda: _add_chain(0.0, CHAIN))
    return ghz, t_add * ghz * 1e9 / CHAIN


def div_sqrt_cycles(ghz):
    """Cycles per double of an independent division (scalar instruction; 256-bit vector) and
    square root (256-bit vector) at ``ghz``: their throughput, over 1024 doubles in L1."""
    a = 1.0 + np.arange(1024) / 1024.0
    b = 2.0 - np.arange(1024) / 2048.0
    out = np.empty_like(a)
    n = 2000
    _divide(a, b, out, 1)
    _divide_vector(a, b, out, 1)
    _sqrt_vector(a, out, 1)
    cycles = ghz * 1e9 / (n * a.shape[0])
    return {'div_scalar': _best(lambda: _divide(a, b, out, n)) * cycles,
            'div_256bit': _best(lambda: _divide_vector(a, b, out, n)) * cycles,
            'sqrt_256bit': _best(lambda: _sqrt_vector(a, out, n)) * cycles}


def peak(ghz, flags):
    """Peak GFLOP/s of one core: ``ghz x doubles per instruction x 2 (FMA) x FMA_UNITS``, for the
    widest vectors of ``flags`` and for 256-bit vectors, with the arithmetic as text."""
    width = 8 if 'avx512f' in flags else 4 if 'avx2' in flags or 'avx' in flags else 2
    fma = 2 if 'fma' in flags else 1
    out = {'ghz_measured': ghz, 'fma_units_per_core_assumed': FMA_UNITS,
           'doubles_per_vector_widest': width, 'flops_per_fma': fma}
    for name, w in (('widest', width), ('256bit', min(width, 4)), ('scalar', 1)):
        out[f'peak_gflops_{name}'] = ghz * w * fma * FMA_UNITS
        unit = 'doubles' if w > 1 else 'double'
        out[f'peak_arithmetic_{name}'] = (f'1 core x {ghz:.2f} GHz x {w} {unit} x {fma} (FMA) x '
                                          f'{FMA_UNITS} FMA units = '
                                          f'{ghz * w * fma * FMA_UNITS:.1f} GFLOP/s')
    # numba compiles without fastmath: no a * b + c is contracted into an FMA, so an instruction
    # does 1 flop per double (the ceiling of this code is half the FMA peak)
    out['peak_gflops_256bit_no_fma'] = ghz * min(width, 4) * FMA_UNITS
    return out


# -- timing -----------------------------------------------------------------------------------
@jit
def scalar_evaluations(m, d, w, out, n):
    for _ in range(n):
        dyn.accelerations(d.x, d.v, m, d, w, out)


@jit_lanes
def lane_evaluations(topo, data, work, out, status, n):
    for _ in range(n):
        lanes.accelerations(data.x, data.v, topo, data, work, out, status)


def network():
    """The FB column as a ``full3d`` network without bar contact."""
    scene = Scene.load(COLUMNS['FB']).with_overrides([('model', 'full3d'),
                                                      ('contact.bars', 'none')])
    return structures.build_network(scene)


def scalar_state(net):
    """``(Model, Data, Work)`` of :func:`solver.kernels.records.plain` at rest, the top level hit
    at 0.1 m/s (velocities projected); :mod:`bench.lanes` times the same state."""
    m, d, w = records.plain(net)
    d.v[net.levels[0, -1], 2] = -0.1
    dyn.project_velocities(d.x, d.v, m.topo, w)
    return m, d, w


def lane_rest(net, k):
    return net.cable_rest_length * (1.0 - 1e-5 * k)


def lanes_count(net, n_lanes):
    """Flops of one evaluation of the ``n_lanes`` lanes of :func:`lane_state`: each lane's own
    :func:`count` (its rest lengths, at ``x0``). The lane kernel also adds a slack cable's zero
    force (9 more a slack cable); with every cable taut, as here, it does exactly these."""
    total = 0
    for k in range(n_lanes):
        m, d, _ = records.plain(net, rest=lane_rest(net, k))
        parts, taut = count(m, d)
        if taut != net.n_cables:
            raise RuntimeError(f'flops: lane {k} has slack cables')
        total += parts['total']['total']
    return total


def lane_state(net, n_lanes, v):
    data = lanes.lane_data([net.x0] * n_lanes, [v] * n_lanes,
                           [lane_rest(net, k) for k in range(n_lanes)],
                           [net.cable_EA] * n_lanes, [np.zeros((net.n_nodes, 3))] * n_lanes)
    return data, lanes.lane_work(net.topology(), net.n_nodes, n_lanes)


def _per_call(call, guess_s):
    """Seconds per call of ``call(n)`` (n calls in one compiled loop of about :data:`SECONDS`,
    n set by one loop of ``guess_s`` a call), the best of :data:`REPEATS` loops."""
    n = max(1, int(SECONDS / guess_s))
    n = max(1, int(SECONDS / (_best(lambda: call(n), 1) / n)))
    return _best(lambda: call(n)) / n


def time_scalar(m, d, w):
    out = np.zeros_like(d.x)

    def call(n):
        scalar_evaluations(m, d, w, out, n)
    call(1)
    return _per_call(call, 5e-6)


def time_lanes(net, n_lanes, v):
    data, work = lane_state(net, n_lanes, v)
    out = np.zeros_like(data.x)
    status = np.zeros(n_lanes, np.int64)

    def call(n):
        lane_evaluations(net.topology(), data, work, out, status, n)
    call(1)
    t = _per_call(call, 2e-6 * n_lanes)
    if not (status == dyn.OK).all():
        raise RuntimeError(f'flops: a lane failed ({status})')
    return t


def main(out_dir='bench/results', log=print):
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    net = network()
    m, d, w = scalar_state(net)
    parts, taut = count(m, d)
    source, _ = count(m, d, source=True)
    flops = parts['total']['total']
    for name in PARTS:
        p = parts[name]
        log(f'flops: {name:18s} {p["total"]:6d}  (add {p["add"]}, mul {p["mul"]}, '
            f'div {p["div"]}, sqrt {p["sqrt"]})')
    log(f'flops: one evaluation {flops} ({taut} of {net.n_cables} cables taut; the source '
        f'writes {source["total"]["total"]})')
    load = [os.getloadavg()[0]]
    info = cpuinfo()
    model = info.get('model name', platform.processor())
    flags = set(info.get('flags', '').split())
    mhz = float(info['cpu MHz']) if 'cpu MHz' in info else None
    clock = [clock_ghz()]
    t1 = time_scalar(m, d, w)
    rows = [{'lanes': 1, 'kernel': 'solver.kernels.dynamics.accelerations',
             'batch_us': t1 * 1e6, 'us_per_instance': t1 * 1e6, 'flops_per_batch': flops,
             'gflops': flops / t1 / 1e9}]
    for n_lanes in LANES:
        lane_flops = lanes_count(net, n_lanes)
        tb = time_lanes(net, n_lanes, d.v)
        rows.append({'lanes': n_lanes, 'kernel': 'solver.kernels.lanes.accelerations',
                     'batch_us': tb * 1e6, 'us_per_instance': tb / n_lanes * 1e6,
                     'flops_per_batch': lane_flops, 'gflops': lane_flops / tb / 1e9})
    clock.append(clock_ghz())
    ghz = max(c[0] for c in clock)          # the peak at the faster of the two clocks
    pk = peak(ghz, flags)
    slow = div_sqrt_cycles(ghz)
    total = parts['total']
    log(f'flops: {model}, cpuinfo {mhz} MHz, measured {clock[0][0]:.2f} and {clock[1][0]:.2f} '
        f'GHz before and after the timings (a float add: {clock[0][1]:.2f} cycles); peak at '
        f'{ghz:.2f} GHz {pk["peak_gflops_widest"]:.1f} GFLOP/s '
        f'({pk["doubles_per_vector_widest"]} doubles), 256-bit {pk["peak_gflops_256bit"]:.1f}, '
        f'scalar {pk["peak_gflops_scalar"]:.1f}; a division {slow["div_scalar"]:.2f} cycles '
        f'(scalar), {slow["div_256bit"]:.2f} per double (256-bit), a sqrt '
        f'{slow["sqrt_256bit"]:.2f} per double (256-bit)')
    for r in rows:
        if r['lanes'] == 1:
            cycles = total['div'] * slow['div_scalar']
        else:
            cycles = total['div'] * slow['div_256bit'] + total['sqrt'] * slow['sqrt_256bit']
        r['div_sqrt_floor_us_per_instance'] = cycles / ghz / 1e3
        r['fraction_of_peak_widest'] = r['gflops'] / pk['peak_gflops_widest']
        r['fraction_of_peak_256bit'] = r['gflops'] / pk['peak_gflops_256bit']
        log(f'flops: B={r["lanes"]:4d}: {r["us_per_instance"]:7.3f} us per instance, '
            f'{r["gflops"]:6.2f} GFLOP/s = {100 * r["fraction_of_peak_widest"]:.1f} % of '
            f'{pk["peak_gflops_widest"]:.0f}, {100 * r["fraction_of_peak_256bit"]:.1f} % of '
            f'the 256-bit {pk["peak_gflops_256bit"]:.0f}; divisions and roots alone '
            f'{r["div_sqrt_floor_us_per_instance"]:.3f} us')
    load.append(os.getloadavg()[0])
    log(f'flops: load average {load[0]:.2f} at the start, {load[1]:.2f} at the end '
        f'({os.cpu_count()} CPUs)')
    path = out / 'flops.json'
    path.write_text(json.dumps({
        'network': 'fb_column full3d, no bar contact (records.plain, every effect off)',
        'n_nodes': int(net.n_nodes), 'n_cables': int(net.n_cables),
        'n_members': int(m.topo.con_tail.shape[0]),
        'band_width': int(m.topo.con_coef.shape[1]),
        'nonzero_coef': int(np.count_nonzero(m.topo.con_coef)),
        'taut_cables': taut,
        'counting': 'add, sub, mul, div, sqrt 1 each; comparisons, negations, copies 0; a slack '
                    'cable 9 (dx, dy, dz, s), a taut one 22 (g * d computed once per axis); '
                    'band entries of zero coef 0; LDL over every band entry',
        'flops_per_evaluation': flops, 'flops_per_evaluation_source': source['total']['total'],
        'flops_by_part': {k: parts[k] for k in PARTS + ('total',)},
        'cpu': {'model_name': model, 'cpuinfo_mhz': mhz,
                'family_model_stepping': [info.get('cpu family'), info.get('model'),
                                          info.get('stepping')],
                'flags': sorted(f for f in flags if f in ('avx', 'avx2', 'fma', 'avx512f')),
                'ghz_measured_before_after_timings': [c[0] for c in clock],
                'float_add_cycles_at_measured_clock': clock[0][1],
                'clock_method': f'{CHAIN} iterations of x ^= x >> 7 (2 dependent 1-cycle '
                                f'integer operations, the register copy between them '
                                f'eliminated at rename), best of {REPEATS}',
                'throughput_cycles_per_double': slow},
        'div_sqrt_floor': 'cycles of the divisions and square roots of one evaluation at their '
                          'measured throughput: scalar row the divisions only (scalar vdivsd; '
                          'the scalar sqrt is not measured), lane rows both at 256-bit '
                          'throughput per double',
        'peak': pk,
        'timing': f'best of {REPEATS} loops of about {SECONDS} s of calls inside one compiled '
                  'function',
        'load_average_start_end': load, 'cpus': os.cpu_count(),
        'rows': rows}, indent=2))
    return [str(path)]


if __name__ == '__main__':
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--out', default='bench/results')
    args = ap.parse_args()
    for p in main(args.out):
        print(p)
