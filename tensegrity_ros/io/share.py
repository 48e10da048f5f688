"""Where the package's data files are: the scenes (``config/scenes/``), the node's parameters
(``config/node.yaml``), the paper's targets (``config/paper/``), the RViz and Foxglove views and
the launch file, in a source checkout, a colcon install and a pip install alike.

A relative path such as ``config/scenes/fb_column.yaml`` is looked up in the working directory
first, then in the package's data directories (:func:`data_dirs`): the source checkout, the share
directory the ament index names (a colcon install that is sourced), the share directory of the
install prefix this module sits in (a colcon install or a ``pip install --prefix`` that is not
sourced) and the interpreter's prefix (a pip install into a virtual environment).
"""
from __future__ import annotations

import sys
from pathlib import Path

PACKAGE = 'tensegrity_ros'


def _ament_share():
    """The share directory the ament index names for the package, or None."""
    try:
        from ament_index_python.packages import get_package_share_directory
        return Path(get_package_share_directory(PACKAGE))
    except (ImportError, LookupError, ValueError, OSError):
        return None


def data_dirs():
    """The directories that may hold the package's ``config/`` and ``launch/``, in the order they
    are searched (each listed once, only those that exist)."""
    here = Path(__file__).resolve()
    found = [here.parents[2]]                     # the source checkout (holds config/)
    found.append(_ament_share())
    # <prefix>/lib/pythonX.Y/site-packages/tensegrity_ros/io/share.py -> <prefix>/share/<pkg>
    found += [p / 'share' / PACKAGE for p in here.parents[3:7]]
    found.append(Path(sys.prefix) / 'share' / PACKAGE)
    out = []
    for d in found:
        if d is not None and (d / 'config').is_dir() and d not in out:
            out.append(d)
    return out


def find_data(path):
    """The file ``path`` names: absolute as given, else relative to the working directory or to
    one of :func:`data_dirs`. Returns the path or None."""
    p = Path(path)
    if p.is_absolute():
        return p if p.is_file() else None
    for base in [Path.cwd()] + data_dirs():
        if (base / p).is_file():
            return base / p
    return None


def searched():
    """The places :func:`find_data` looks in, as text for a message."""
    return ', '.join(['the working directory'] + [str(d) for d in data_dirs()])
