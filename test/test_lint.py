"""Style as the ROS 2 Python packages lint it (ament_flake8): 99 columns, no unused or undefined
names, no syntax errors; checked with ruff on every tracked Python file."""
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_sources_pass_the_linter():
    ruff = Path(sys.executable).parent / 'ruff'
    if not ruff.exists():
        ruff = shutil.which('ruff')
    if ruff is None:
        pytest.skip('ruff is not installed (pip install -e .[test])')
    files = subprocess.run(['git', 'ls-files', '*.py'], cwd=ROOT, capture_output=True,
                           text=True, check=True).stdout.split()
    res = subprocess.run([str(ruff), 'check', '--select', 'E501,E9,F', '--line-length', '99',
                          '--output-format', 'concise', *files], cwd=ROOT, capture_output=True,
                         text=True)
    assert res.returncode == 0, res.stdout + res.stderr
