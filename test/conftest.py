"""Test-wide settings: ROS 2 discovery stays on this machine; headless plotting."""
import os

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('MPLBACKEND', 'Agg')


def pytest_collection_finish(session):
    """Before the first test of a run of several test files, compile the solver's kernels on
    every core (a fresh cache otherwise compiles them one by one inside the tests):
    solver.simulate.precompile. A run of one file compiles only what its tests call."""
    import sys
    if len({item.path for item in session.items}) < 2:
        return
    from solver.simulate.precompile import compile_all
    try:
        compile_all(log=lambda msg: print(msg, file=sys.stderr, flush=True))
    except RuntimeError as exc:       # the tests that reach the failing kernel will say why
        print(f'warning: {exc}', file=sys.stderr, flush=True)
