"""The layered layout (docs/architecture.md): every import in the product goes to a room below
its own (or stays in its room), no import circle, no import of ``bench``; every tracked Python
file under 500 lines; and the checks themselves catch a circle, an upward import and a long file
added on purpose."""
from __future__ import annotations

import ast
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ('solver', 'tensegrity_ros')
# rooms, lowest first; rooms of one rank are siblings and never import each other
RANKS = [
    {'solver.compiled', 'solver.status'},
    {'solver.kernels'},
    {'solver.build', 'solver.integrators'},
    {'solver.models'},
    {'solver.analysis'},
    {'solver.simulate'},
    {'solver.studies'},
    {'solver'},                                   # the package's face (solver/__init__.py)
    {'tensegrity_ros.msgs'},
    {'tensegrity_ros.io'},
    {'tensegrity_ros.node', 'tensegrity_ros.studies'},
    {'tensegrity_ros.commands'},
    {'tensegrity_ros.cli', 'tensegrity_ros'},
]
RANK = {room: i for i, rooms in enumerate(RANKS) for room in rooms}


def modules(root):
    """Module name -> file of every product module below ``root``."""
    out = {}
    for pkg in PACKAGES:
        for path in sorted((root / pkg).rglob('*.py')):
            parts = list(path.relative_to(root).with_suffix('').parts)
            if parts[-1] == '__init__':
                parts.pop()
            out['.'.join(parts)] = path
    return out


def imports(name, path, known):
    """The product modules (and ``bench``) that module ``name`` imports anywhere in its file,
    lazy imports inside functions included."""
    is_pkg = path.name == '__init__.py'
    package = name if is_pkg else name.rpartition('.')[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ''
            if node.level:
                anchor = package.split('.')
                anchor = anchor[:len(anchor) - (node.level - 1)]
                base = '.'.join(anchor + ([base] if base else []))
            targets = [f'{base}.{a.name}' if f'{base}.{a.name}' in known else base
                       for a in node.names]
        else:
            continue
        for target in targets:
            top = target.split('.')[0]
            if top == 'bench':
                found.add('bench')
            elif top in PACKAGES:
                while target not in known and '.' in target:
                    target = target.rpartition('.')[0]
                if target != name:
                    found.add(target)
    return found


def room(module):
    """The room of a module: the longest prefix listed in :data:`RANKS`."""
    parts = module.split('.')
    for n in range(len(parts), 0, -1):
        if '.'.join(parts[:n]) in RANK:
            return '.'.join(parts[:n])
    raise AssertionError(f'{module} is in no room of the layout (add it to RANKS)')


def violations(root):
    """Every upward or sideways import, every import of ``bench`` and every import circle of
    the product below ``root``, as sentences."""
    known = modules(root)
    graph = {name: imports(name, path, known) for name, path in known.items()}
    bad = []
    for name, targets in sorted(graph.items()):
        for target in sorted(targets):
            if target == 'bench':
                bad.append(f'{name} imports bench (benchmarks are never imported by the product)')
                continue
            a, b = room(name), room(target)
            if a != b and RANK[b] >= RANK[a] and not name.startswith(b + '.'):
                bad.append(f'{name} ({a}) imports {target} ({b}), a room that is not below it')
    # circles: depth-first search for a back edge
    state, stack = {}, []

    def visit(n):
        state[n] = 'open'
        stack.append(n)
        for m in sorted(graph.get(n, ())):
            if m == 'bench':
                continue
            if state.get(m) == 'open':
                bad.append('import circle: ' + ' -> '.join(stack[stack.index(m):] + [m]))
            elif m not in state:
                visit(m)
        stack.pop()
        state[n] = 'done'
    for n in sorted(graph):
        if n not in state:
            visit(n)
    return bad


def test_the_product_imports_only_downward_without_circles():
    assert violations(ROOT) == []


@pytest.fixture
def copy_of_the_product(tmp_path):
    for pkg in PACKAGES:
        shutil.copytree(ROOT / pkg, tmp_path / pkg, ignore=shutil.ignore_patterns('__pycache__'))
    return tmp_path


def _append(path, line):
    path.write_text(path.read_text() + f'\n{line}\n')


def test_the_check_finds_a_circle_added_on_purpose(copy_of_the_product):
    root = copy_of_the_product
    _append(root / 'solver' / 'kernels' / 'rotation.py', 'from solver.kernels import contact')
    found = violations(root)
    assert any(v.startswith('import circle') and 'solver.kernels.rotation' in v for v in found), \
        found


def test_the_check_finds_a_lazy_upward_import_and_bench(copy_of_the_product):
    root = copy_of_the_product
    _append(root / 'solver' / 'kernels' / 'dynamics.py',
            'def _late():\n    from solver.simulate import simulation  # noqa: F401')
    _append(root / 'tensegrity_ros' / 'msgs' / 'style.py', 'import bench.main  # noqa: F401')
    found = violations(root)
    assert any('solver.kernels.dynamics (solver.kernels) imports solver.simulate.simulation'
               in v for v in found), found
    assert any('tensegrity_ros.msgs.style imports bench' in v for v in found), found
    assert any(v.startswith('import circle') for v in found), found     # dynamics <-> simulate


def test_sibling_rooms_do_not_import_each_other(copy_of_the_product):
    root = copy_of_the_product
    _append(root / 'tensegrity_ros' / 'node' / 'commands.py',
            'from tensegrity_ros.studies import sweep  # noqa: F401')
    found = violations(root)
    assert any('tensegrity_ros.node.commands' in v and 'not below it' in v for v in found), found


MAX_LINES = 500


def long_files(paths, limit=MAX_LINES):
    """``(path, line count)`` of every file of ``paths`` with ``limit`` lines or more."""
    out = []
    for path in paths:
        with open(path, 'rb') as fh:
            n = sum(1 for _ in fh)
        if n >= limit:
            out.append((path, n))
    return out


def _tracked_python_files():
    files = subprocess.run(['git', 'ls-files', '*.py'], cwd=ROOT, capture_output=True,
                           text=True, check=True).stdout.split()
    return [ROOT / f for f in files]


def _long_files_message(found):
    return (f'files of {MAX_LINES} lines or more (split them into modules of one concern):\n'
            + '\n'.join(f'  {p}: {n} lines' for p, n in found))


def test_every_tracked_python_file_is_under_500_lines():
    files = _tracked_python_files()
    assert len(files) > 100                       # the listing found the repository's files
    found = long_files(files)
    assert not found, _long_files_message([(p.relative_to(ROOT), n) for p, n in found])


def test_the_line_check_flags_a_long_file_written_on_purpose(tmp_path):
    short, limit, long = tmp_path / 'short.py', tmp_path / 'limit.py', tmp_path / 'long.py'
    short.write_text('x = 1\n' * (MAX_LINES - 1))
    limit.write_text('x = 1\n' * MAX_LINES)
    long.write_text('x = 1\n' * (MAX_LINES + 20) + 'y = 2')           # no final newline
    found = long_files([short, limit, long])
    assert found == [(limit, MAX_LINES), (long, MAX_LINES + 21)]
    message = _long_files_message(found)
    assert f'{limit}: {MAX_LINES} lines' in message
    assert f'{long}: {MAX_LINES + 21} lines' in message
