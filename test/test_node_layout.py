"""The node stays thin: ``TensegritySim`` at most 300 lines, and every use of rclpy's private
state in the node carries the reason (no public API does the job) in a comment just above it."""
import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NODE = ROOT / 'tensegrity_ros' / 'node'
MAX_CLASS_LINES = 300
PRIVATE = re.compile(r'_parameter_overrides|\._parameters\b|_rclpy_pybind11|handle\.take_message'
                     r'|_check_undeclared_parameters')


def class_lines(path, name):
    """Lines of class ``name`` in ``path``, decorators to its last line."""
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ClassDef) and node.name == name:
            first = min([node.lineno] + [d.lineno for d in node.decorator_list])
            return node.end_lineno - first + 1
    raise AssertionError(f'no class {name} in {path}')


def test_the_node_class_is_at_most_300_lines():
    n = class_lines(NODE / 'node.py', 'TensegritySim')
    assert 100 < n <= MAX_CLASS_LINES, f'TensegritySim is {n} lines (at most {MAX_CLASS_LINES})'


def test_the_count_sees_a_long_class(tmp_path):
    path = tmp_path / 'long.py'
    path.write_text('class A:\n' + '    x = 1\n' * 400 + '\n\nclass B:\n    pass\n')
    assert class_lines(path, 'A') == 401 and class_lines(path, 'B') == 2


def uses_without_reason(paths):
    """``(file, line)`` of each use of rclpy's private state with no comment in the three lines
    above it (or on it)."""
    found = []
    for path in paths:
        lines = path.read_text().splitlines()
        for i, line in enumerate(lines):
            if PRIVATE.search(line.split('#')[0]) is None:
                continue
            near = lines[max(0, i - 3):i + 1]
            if not any('#' in x or 'rclpy has no public' in x for x in near):
                found.append((path.name, i + 1))
    return found


def test_private_rclpy_state_only_with_its_reason():
    paths = sorted(NODE.glob('*.py'))
    assert sum(bool(PRIVATE.search(p.read_text())) for p in paths) >= 2      # the check sees some
    assert uses_without_reason(paths) == []


def test_the_reason_check_flags_a_bare_use(tmp_path):
    path = tmp_path / 'bare.py'
    path.write_text('x = 1\ny = 2\nz = 3\n\n\ndef f(node):\n    return node._parameters\n')
    assert uses_without_reason([path]) == [('bare.py', 7)]
