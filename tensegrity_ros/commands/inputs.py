"""Checks of command-line input that stop a command before anything runs, with one line (a
ValueError, which :func:`tensegrity_ros.cli.main` prints and exits 2 on): output directories,
ROS parameter files, the demo's velocities and prestrains."""
from __future__ import annotations

from pathlib import Path


def check_out(path, option='--out'):
    """Raise ValueError unless ``path`` can be an output directory: it and every part of
    it that exists are directories (nothing is created here)."""
    p = Path(path)
    for part in (p, *p.parents):
        if part.exists():
            if not part.is_dir():
                what = 'is a file' if part == p else f'{part} is a file'
                raise ValueError(f'{option} {path}: {what}, not a directory')
            return


def check_params_files(ros_args):
    """Raise ValueError for a ``--params-file`` of ``ros_args`` that cannot be read, is not YAML
    or not in rcl's layout (rcl would stop with a traceback of its parser's message)."""
    import yaml
    args = list(ros_args or [])
    for flag, value in zip(args, args[1:] + [None]):
        if flag != '--params-file':
            continue
        if value is None:
            raise ValueError('--params-file: give a file')
        try:
            data = yaml.safe_load(Path(value).read_text())
        except OSError as exc:
            raise ValueError(f'--params-file {value}: cannot read ({exc.strerror})') from None
        except yaml.YAMLError as exc:
            raise ValueError(f'--params-file {value}: not valid YAML '
                            f'({getattr(exc, "problem", None) or exc})') from None
        where = _params_layout(data)
        if where is not None:
            raise ValueError(f'--params-file {value}: expected NODE: {{ros__parameters: {{NAME: '
                            f'VALUE}}}} (NODE may sit in namespaces), {where}')


def _params_layout(data, at=''):
    """Where the mapping ``data`` of a parameters file breaks rcl's layout (namespaces, a node,
    ``ros__parameters`` holding a mapping), or None."""
    if not isinstance(data, dict) or not data:
        return f'got {type(data).__name__ if data is not None else "nothing"} at {at or "the top"}'
    for key, sub in data.items():
        path = f'{at}/{key}' if at else str(key)
        if key == 'ros__parameters':
            if not isinstance(sub, dict):
                return f'{path} holds {type(sub).__name__}, not NAME: VALUE pairs'
            continue
        problem = _params_layout(sub, path)
        if problem is not None:
            return problem
    return None


def demo_values(args):
    """``(v0 list, prestrain list or None)`` of ``demo --v0 --prestrain``, checked."""
    try:
        v0 = [float(v) for v in args.v0.split(',')]
        prestrain = None if args.prestrain is None else [float(p) for p in
                                                         args.prestrain.split(',')]
    except ValueError:
        raise ValueError('--v0 and --prestrain take numbers separated by commas') from None
    bad = [v for v in v0 if not (-10.0 <= v <= 10.0)]
    if bad:
        raise ValueError(f'--v0: {bad[0]!r} m/s is not a number within [-10, 10]')
    bad = [p for p in prestrain or () if not (0.0 <= p <= 0.5)]
    if bad:
        raise ValueError(f'--prestrain: {bad[0]!r} is not a number within [0, 0.5]')
    return v0, prestrain
