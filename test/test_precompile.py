"""tensegrity compile / solver.simulate.precompile: the kernels compiled in parallel processes
(at the start of a run of several test files) are found by a later process, which then compiles
nothing."""
import re
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


def test_every_integrator_is_in_a_group():
    from solver.integrators import registry
    methods = {m for group in precompile.GROUPS for m in group}
    assert set(registry.METHODS) | {'chain1d'} == methods


def test_the_cli_refuses_zero_processes():
    out = subprocess.run([sys.executable, '-m', 'tensegrity_ros.cli', 'compile', '--processes',
                          '0'], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 2
    assert out.stderr.strip() == 'tensegrity: --processes: must be at least 1, got 0'


def test_a_group_that_gives_no_result_in_time_is_killed_and_named(tmp_path):
    """On an empty cache with a 0.5 s limit: one line naming every group, exit not 0, no
    compiler process left behind, no marker written."""
    import os
    code = ('import sys\nfrom solver.simulate.precompile import compile_all\n'
            'try:\n    compile_all(timeout_s=0.5, log=lambda m: None)\n'
            'except RuntimeError as exc:\n    print(exc)\n    sys.exit(3)\n')
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    out = subprocess.run([sys.executable, '-c', code], cwd=ROOT, env=env, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 3, out.stderr[-2000:]
    lines = out.stdout.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('precompile failed for ')
    for group in precompile.GROUPS:
        assert f'{"/".join(group)}: no result after 0.5 s' in lines[0]
    assert not list(tmp_path.glob('*/.precompiled'))
    left = subprocess.run(['pgrep', '-f', 'solver.simulate.precompile'], capture_output=True,
                          text=True)
    assert left.stdout.strip() == ''


def test_the_kernel_cache_key_covers_what_compiled_code_can_reach(tmp_path):
    """The cache folder's hash (``solver._jit.kernel_source_hash``) covers the modules that
    import ``solver._jit`` and every solver module they import: an edit to a kernel, or to a
    module a kernel module imports, starts a fresh cache; an edit to the run loop or the
    convergence check does not (the sweep's point ids still follow every solver file)."""
    import shutil
    import solver
    from solver import _jit
    root = Path(solver.__file__).parent
    reached = {p.relative_to(root).as_posix() for p in _jit.kernel_files(root)}
    uses = re.compile(r'^\s*(from|import)\s+(numba|solver\._jit|solver import _jit)', re.M)
    for path in root.rglob('*.py'):
        rel = path.relative_to(root).as_posix()
        if uses.search(path.read_text()):
            assert rel in reached, rel
    assert 'simulate/runner.py' not in reached and 'kernels/dynamics.py' in reached
    src = tmp_path / 'solver'
    shutil.copytree(root, src, ignore=shutil.ignore_patterns('__pycache__'))
    key, full = _jit.kernel_source_hash(src), _jit.source_hash(src)
    assert key == _jit.kernel_source_hash(root)

    def edit(rel, text='\n# changed\n'):
        path = src / rel
        path.write_text(path.read_text() + text)
        return _jit.kernel_source_hash(src)
    assert edit('simulate/convergence.py') == key and _jit.source_hash(src) != full
    assert edit('build/scene.py') != key              # simulation.py imports it
    key = _jit.kernel_source_hash(src)
    assert edit('simulate/runner.py', '\nfrom solver._jit import jit\n') != key
    # relative imports count too
    pkg = tmp_path / 'pkg'
    pkg.mkdir()
    for name, text in {'__init__': '', '_jit': '', 'a': 'from . import b\nfrom ._jit import x\n',
                       'b': 'from .c import y\n', 'c': '', 'd': 'import os\n'}.items():
        (pkg / f'{name}.py').write_text(text)
    assert sorted(p.stem for p in _jit.kernel_files(pkg)) == ['__init__', '_jit', 'a', 'b', 'c']
