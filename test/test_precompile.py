"""tensegrity compile / solver.simulate.precompile: the kernels compiled in parallel processes
(at the start of a run of several test files) are found by a later process, which then compiles
nothing."""
import subprocess
import sys
from pathlib import Path

from solver.simulate import precompile

ROOT = Path(__file__).resolve().parents[1]

COUNT_COMPILES = """
import sys
from numba.core import event
from solver.simulate import precompile
names = []
class Count(event.Listener):
    def on_start(self, ev):
        names.append(getattr(getattr((ev.data or {}).get('dispatcher'), 'py_func', None),
                             '__name__', '?'))
    def on_end(self, ev):
        pass
event.register('numba:compile', Count())
for method in sys.argv[1:]:
    precompile._exercise(method)
print(','.join(names))
"""


def test_a_later_process_loads_every_kernel_from_the_cache():
    precompile.compile_all()        # done already when the suite runs (conftest)
    assert precompile._marker().exists()
    assert precompile.compile_all() == 0.0          # the marker: a second call returns at once
    methods = [m for group in precompile.GROUPS for m in group]
    out = subprocess.run([sys.executable, '-c', COUNT_COMPILES, *methods], cwd=ROOT,
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == '', f'compiled again: {out.stdout.strip()}'


def test_compilers_starting_at_once_all_find_the_cache_folder_writable(tmp_path):
    """solver.compiled._writable asked at once from two threads, 3,000 times each (as the
    compiling processes of precompile ask when they start together): always yes. A probe file
    shared by name made some answers no, and such a process compiled into the fallback cache
    in the home folder, where later processes do not look."""
    import threading
    from solver import compiled
    answers = []

    def ask():
        answers.extend(compiled._writable(tmp_path) for _ in range(3000))
    threads = [threading.Thread(target=ask) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(answers) == 6000 and all(answers)
    assert list(tmp_path.iterdir()) == []           # no probe left behind


def test_the_last_pass_compiles_what_the_parallel_ones_lost(tmp_path):
    """A copy of the complete cache without the index of one kernel (as when two compiling
    processes rewrite it at once): the last pass compiles that kernel, and a pass after it
    compiles nothing."""
    import os
    import shutil
    precompile.compile_all()
    cache = precompile._marker().parent
    copy = tmp_path / f'tensegrity-{cache.name}'        # where NUMBA_CACHE_DIR puts it
    shutil.copytree(cache, copy)
    lost = list(copy.rglob('rk4._rattle_ramped-*.nbi'))
    assert len(lost) == 1
    lost[0].unlink()
    code = 'from solver.simulate.precompile import _sole_pass\nprint(_sole_pass(600.0))'
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    passes = [subprocess.run([sys.executable, '-c', code], cwd=ROOT, env=env, text=True,
                             capture_output=True, timeout=600) for _ in range(2)]
    for out in passes:
        assert out.returncode == 0, out.stderr[-2000:]
    assert '_rattle_ramped' in passes[0].stdout
    assert passes[1].stdout.strip() == '[]'


def test_every_integrator_is_in_a_group():
    from solver.integrators import registry
    methods = {m for group in precompile.GROUPS for m in group}
    assert set(registry.METHODS) | {'chain1d', 'lanes'} == methods


def test_the_cli_refuses_zero_processes():
    out = subprocess.run([sys.executable, '-m', 'tensegrity_ros.cli', 'compile', '--processes',
                          '0'], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 2
    assert out.stderr.strip() == 'tensegrity: --processes: must be at least 1, got 0'


def _limited(tmp_path, call):
    """``call`` (a line of code that calls into ``precompile``) in a process of its own on an
    empty cache in ``tmp_path``: the message of the RuntimeError it raised (exit 3 expected),
    after checking that no compiler process of that cache is left (their environment names
    it: other tests, on other workers, may be compiling at the same time)."""
    import os
    code = ('import sys\nfrom solver.simulate import precompile\n'
            f'try:\n    {call}\n'
            'except RuntimeError as exc:\n    print(exc)\n    sys.exit(3)\n')
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    out = subprocess.run([sys.executable, '-c', code], cwd=ROOT, env=env, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 3, out.stderr[-2000:]
    left = subprocess.run(['pgrep', '-f', 'solver.simulate.precompile'], capture_output=True,
                          text=True).stdout.split()
    assert [pid for pid in left if _environ_holds(pid, str(tmp_path))] == []
    return out.stdout.strip()


def test_a_group_that_gives_no_result_in_time_is_killed_and_named(tmp_path):
    """On an empty cache with a 0.5 s limit: one line naming every group, exit not 0, no
    compiler process left behind, no marker written."""
    lines = _limited(tmp_path, 'precompile.compile_all(timeout_s=0.5, log=lambda m: None)'
                     ).splitlines()
    assert len(lines) == 1 and lines[0].startswith('precompile failed for ')
    for group in precompile.GROUPS:
        assert f'{"/".join(group)}: no result after 0.5 s' in lines[0]
    assert not list(tmp_path.glob('*/.precompiled'))


def test_a_last_pass_that_gives_no_result_in_time_is_killed_and_named(tmp_path):
    """The single-process pass on an empty cache with a 0.5 s limit: a RuntimeError that says
    so (what compile_all's callers catch), and its process is gone."""
    assert _limited(tmp_path, 'precompile._sole_pass(0.5)') == (
        'precompile failed: its last pass gave no result after 0.5 s')


def _environ_holds(pid, text):
    """Whether the environment of process ``pid`` holds ``text`` (False once it is gone)."""
    try:
        return text.encode() in Path(f'/proc/{pid}/environ').read_bytes()
    except OSError:
        return False
