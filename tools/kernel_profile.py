"""Where the compiled kernels' time goes, kernel by kernel:

    python tools/kernel_profile.py [--v0 0.17,0.18] [--points 64] [--t-end 1] [--top 25]

Runs one batch of the 1,024-point sweep of docs/sweeps.md (the FB column, prestrains
0.001-0.004, the given impact speeds; by default one 64-point batch of 1 s runs) as lanes on
one thread, under Linux ``perf record`` (the Debian package ``linux-perf``:
``tools/install_perf.sh``). perf does not see numba's cached code by itself, so the profiled
process writes ``/tmp/perf-<pid>.map`` before it exits: every compiled overload's functions
and their addresses, which ``perf report`` reads. Prints each kernel's share of the samples in
compiled code (and of all samples), the largest first.
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def demangle(symbol):
    """``solver.kernels.lanes.cables`` from numba's mangled ``_ZN6solver7kernels5lanes6cables
    B4v3...E...``, or None for a symbol that is not a solver kernel's."""
    m = re.search(r'_ZN(\d.*)', symbol)
    if m is None:
        return None
    s, parts = m.group(1), []
    while s and s[0].isdigit():
        digits = re.match(r'\d+', s).group()
        n = int(digits)
        parts.append(s[len(digits):len(digits) + n])
        s = s[len(digits) + n:]
    return '.'.join(parts) if parts and parts[0] == 'solver' else None


def shares(report):
    """``(compiled share of all samples %, [(kernel, % of compiled, % of all), ...])`` from the
    text of ``perf report --sort symbol --stdio``, the kernels summed over their overloads."""
    total, by = 0.0, {}
    for line in report.splitlines():
        m = re.match(r'\s*([\d.]+)%\s+\S+\s+(.*)', line)
        if m is None:
            continue
        name = demangle(m.group(2).split()[0]) if m.group(2).split() else None
        if name is None:
            continue
        share = float(m.group(1))
        by[name] = by.get(name, 0.0) + share
        total += share
    rows = sorted(((k, 100.0 * v / total if total else 0.0, v) for k, v in by.items()),
                  key=lambda r: -r[1])
    return total, rows


def write_map(path=None):
    """Write ``/tmp/perf-<pid>.map`` (``path``): every compiled overload's functions, their
    addresses and the room to the next one (perf's JIT map format). Returns the count."""
    import gc
    from numba.core.registry import CPUDispatcher
    entries = {}
    for obj in gc.get_objects():
        if not isinstance(obj, CPUDispatcher):
            continue
        for cres in list(obj.overloads.values()):
            lib = cres.library
            module = getattr(lib, '_shared_module', None) or getattr(lib, '_final_module', None)
            if module is None:
                continue
            for fn in module.functions:
                if fn.is_declaration:
                    continue
                try:
                    addr = lib.get_pointer_to_function(fn.name)
                except Exception:               # noqa: BLE001 - a symbol it does not define
                    continue
                if addr:
                    entries[addr] = fn.name
    addrs = sorted(entries)
    path = path or f'/tmp/perf-{os.getpid()}.map'
    with open(path, 'w') as fh:
        for a, b in zip(addrs, addrs[1:] + [addrs[-1] + 4096] if addrs else []):
            fh.write(f'{a:x} {min(b - a, 1 << 20):x} {entries[a]}\n')
    return len(addrs)


def workload(v0s, points, t_end):
    """One batch of the sweep's points, as lanes on one thread (the profiled part)."""
    sys.path.insert(0, str(ROOT))
    from tensegrity_ros.studies import sweep as sw
    with tempfile.TemporaryDirectory() as tmp:
        per_v0 = max(1, points // len(v0s))
        s = sw.build(ROOT / 'config/scenes/fb_column.yaml',
                     ['loading.impact.v0=' + ','.join(str(v) for v in v0s),
                      f'prestrain=0.001:0.004:{per_v0}'], out=Path(tmp) / 'p', t_end=t_end)
        sw.run_points(s.scene, s.runs(), threads=1)


def main(argv=None):
    p = argparse.ArgumentParser(prog='python tools/kernel_profile.py',
                                description='the compiled kernels\' shares of a sweep batch')
    p.add_argument('--v0', default='0.17,0.18', help='impact speeds m/s, comma separated')
    p.add_argument('--points', type=int, default=64, help='points of the batch')
    p.add_argument('--t-end', type=float, default=1.0, help='simulated time of a point, s')
    p.add_argument('--top', type=int, default=25, help='kernels to print')
    p.add_argument('--child', action='store_true', help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    try:
        v0s = [float(v) for v in a.v0.split(',')]
    except ValueError:
        p.error(f'--v0: {a.v0!r} is not a comma-separated list of speeds')
    if a.child:
        workload(v0s, a.points, a.t_end)
        write_map()
        return 0
    perf = shutil.which('perf')
    if perf is None:
        print('kernel_profile: perf not found (install it: tools/install_perf.sh)',
              file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / 'perf.data'
        cmd = [perf, 'record', '-q', '-F', '999', '-o', str(data), '--', sys.executable,
               __file__, '--child', '--v0', a.v0, '--points', str(a.points), '--t-end',
               str(a.t_end)]
        run = subprocess.run(cmd, capture_output=True, text=True)
        if run.returncode != 0:
            print(f'kernel_profile: perf record failed: {run.stderr.strip().splitlines()[-1:]}',
                  file=sys.stderr)
            return 1
        report = subprocess.run([perf, 'report', '-i', str(data), '--sort', 'symbol',
                                 '--stdio'], capture_output=True, text=True).stdout
    total, rows = shares(report)
    print(f'compiled code: {total:.1f} % of the samples')
    print(f'{"kernel":60s} {"% compiled":>10s} {"% all":>7s}')
    for name, of_jit, of_all in rows[:a.top]:
        print(f'{name:60s} {of_jit:10.1f} {of_all:7.2f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
