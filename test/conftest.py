"""Test-wide settings: ROS 2 discovery stays on this machine; headless plotting; the solver's
kernels compiled once before a run of several test files."""
import os
import sys

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('MPLBACKEND', 'Agg')


def _compile():
    """solver.simulate.precompile: every kernel into the cache on every core (a fresh cache
    otherwise compiles them one by one inside the tests)."""
    from solver.simulate.precompile import compile_all
    try:
        compile_all(log=lambda msg: print(msg, file=sys.stderr, flush=True))
    except RuntimeError as exc:       # the tests that reach the failing kernel will say why
        print(f'warning: {exc}', file=sys.stderr, flush=True)


def _several_files(args):
    """Whether the command line names more than one test file (a folder counts as several)."""
    paths = [a.split('::')[0] for a in args if not a.startswith('-')] or ['test']
    return len(set(paths)) > 1 or os.path.isdir(paths[0])


def pytest_configure(config):
    """With pytest-xdist (``-n``) the main process compiles before it starts its workers, so
    no two workers compile the same kernels at once; a worker never compiles here."""
    if hasattr(config, 'workerinput'):
        return
    if getattr(config.option, 'numprocesses', None) and _several_files(config.args):
        _compile()


def pytest_collection_finish(session):
    """Without pytest-xdist: compile before the first test of a run of several test files. A run
    of one file compiles only what its tests call."""
    config = session.config
    if hasattr(config, 'workerinput') or getattr(config.option, 'numprocesses', None):
        return
    if len({item.path for item in session.items}) < 2:
        return
    _compile()
