"""The `tensegrity run --json` summary of every shipped scene, timing fields left out.

    python -m tools.scene_summaries --out BEFORE.json        # write the summaries
    python -m tools.scene_summaries --compare BEFORE.json    # run again and list every difference
    python -m tools.scene_summaries --out LINE.json --set contact.bars=none   # a setting for all

A refactoring that must keep behaviour checks its work with this pair: the summaries of
config/scenes/*.yaml before and after must be identical (bit for bit in every float) apart from
wall-clock fields. Exit 1 when a difference is found.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TIMING_WORDS = ('wall', 'cpu', 'elapsed', 'seconds_per', 'real_time', 'time_s')


def _is_timing(key: str) -> bool:
    return any(word in key for word in TIMING_WORDS)


def _strip(value):
    if isinstance(value, dict):
        return {k: _strip(v) for k, v in value.items() if not _is_timing(k)}
    if isinstance(value, list):
        return [_strip(v) for v in value]
    return value


def summaries(t_end: float, sets=()) -> dict:
    exe = Path(sys.executable).with_name('tensegrity')
    out = {}
    for scene in sorted((ROOT / 'config' / 'scenes').glob('*.yaml')):
        extra = [arg for s in sets for arg in ('--set', s)]
        proc = subprocess.run([str(exe), 'run', str(scene), '--json', '--t-end', str(t_end),
                               *extra], capture_output=True, text=True, cwd=ROOT)
        out[scene.name] = (_strip(json.loads(proc.stdout)) if proc.returncode == 0
                           else {'exit': proc.returncode, 'stderr': proc.stderr.strip()})
    return out


def _differences(a, b, path=''):
    if isinstance(a, dict) and isinstance(b, dict):
        for key in sorted(set(a) | set(b)):
            yield from _differences(a.get(key), b.get(key), f'{path}.{key}' if path else key)
    elif isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        for i, (x, y) in enumerate(zip(a, b)):
            yield from _differences(x, y, f'{path}[{i}]')
    elif a != b:
        yield f'{path}: {a!r} != {b!r}'


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--out', type=Path, help='write the summaries to this JSON file')
    parser.add_argument('--compare', type=Path, help='compare with summaries written before')
    parser.add_argument('--t-end', type=float, default=0.6, help='simulated time per scene, s')
    parser.add_argument('--set', action='append', default=[], metavar='KEY=VALUE',
                        help='a scene value for every scene (repeatable)')
    args = parser.parse_args(argv)
    now = summaries(args.t_end, args.set)
    if args.out:
        args.out.write_text(json.dumps(now, indent=1, sort_keys=True))
    if args.compare:
        diffs = list(_differences(json.loads(args.compare.read_text()), now))
        for line in diffs:
            print(line)
        print(f'{len(now)} scenes, {len(diffs)} differences')
        return 1 if diffs else 0
    return 0


if __name__ == '__main__':
    sys.exit(main())
