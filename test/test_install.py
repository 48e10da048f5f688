"""An install works away from the checkout: the package installed into a temporary prefix (pip,
as colcon's ament_python build does with setup.py's data_files) holds every data file the docs
use, and its node, started from ``/`` with default parameters, finds its scene in the prefix's
share directory and runs; the CLI finds the paper's targets there too.

The prefix is a fixed folder under the temporary directory, installed afresh when the tracked
files changed since it was installed (a hash of them is kept beside it), so that numba's cache in
the install (keyed by the source file's path and time) serves a later run; a first run compiles
the kernels for that path (a minute or two)."""
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOMAIN = 10 + (os.getpid() + 17) % 20
PREFIX = Path(tempfile.gettempdir()) / 'tensegrity_ros-install-test'
SHARE = PREFIX / 'share' / 'tensegrity_ros'
SITE = PREFIX / 'lib' / f'python{sys.version_info[0]}.{sys.version_info[1]}' / 'site-packages'
# what the docs use from config/ and launch/, and the ament index entry
DATA = ['config/node.yaml', 'config/tensegrity.rviz', 'config/tensegrity.foxglove.json',
        'config/paper/fb_target.yaml', 'launch/tensegrity.launch.py', 'package.xml']


def _tracked(pattern):
    out = subprocess.run(['git', 'ls-files', pattern], cwd=ROOT, capture_output=True, text=True,
                         check=True).stdout.split()
    return out


def _sources_hash():
    """sha256 of the paths and contents of every tracked file (what the install is made of)."""
    import hashlib
    digest = hashlib.sha256()
    for rel in _tracked('*'):
        digest.update(rel.encode() + b'\0' + (ROOT / rel).read_bytes() + b'\0')
    return digest.hexdigest()


@pytest.fixture(scope='module')
def prefix(tmp_path_factory):
    import shutil
    stamp = PREFIX / '.sources-sha256'
    want = _sources_hash()
    if stamp.is_file() and stamp.read_text() == want and (PREFIX / 'bin').is_dir():
        return PREFIX                                   # the same sources: installed already
    shutil.rmtree(PREFIX, ignore_errors=True)
    src = tmp_path_factory.mktemp('src')             # the tracked files: no build/ in the checkout
    for rel in _tracked('*'):
        (src / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / rel, src / rel)
    scripts = sorted(Path(sys.executable).parent.glob('tensegrity*'))
    # --ignore-installed: the environment's own install (editable) stays as it is
    r = subprocess.run([sys.executable, '-m', 'pip', 'install', '--quiet', '--no-deps',
                        '--ignore-installed',
                        '--no-build-isolation', '--prefix', str(PREFIX), str(src)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert sorted(Path(sys.executable).parent.glob('tensegrity*')) == scripts   # env untouched
    stamp.write_text(want)
    return PREFIX


def _env():
    return dict(os.environ, PYTHONPATH=str(SITE), ROS_DOMAIN_ID=str(DOMAIN),
                ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')


def test_the_install_holds_every_data_file(prefix):
    scenes = _tracked('config/scenes/*.yaml')
    assert len(scenes) >= 8
    for rel in DATA + scenes:
        assert (SHARE / rel).is_file(), rel
    assert (PREFIX / 'share/ament_index/resource_index/packages/tensegrity_ros').is_file()
    for rel in scenes + ['config/paper/fb_target.yaml']:
        assert (SHARE / rel).read_bytes() == (ROOT / rel).read_bytes()


def test_the_installed_package_finds_its_data_from_another_directory(prefix):
    code = ('import tensegrity_ros, sys\n'
            'from tensegrity_ros.io.share import find_data\n'
            'print(tensegrity_ros.__file__)\n'
            'for p in sys.argv[1:]: print(find_data(p))\n')
    r = subprocess.run([sys.executable, '-c', code, 'config/scenes/fb_column.yaml',
                        'config/paper/fb_target.yaml', 'config/node.yaml'], cwd='/', env=_env(),
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    module, *found = r.stdout.split()
    assert Path(module).is_relative_to(SITE)               # the installed copy, not the checkout
    assert found == [str(SHARE / 'config/scenes/fb_column.yaml'),
                     str(SHARE / 'config/paper/fb_target.yaml'), str(SHARE / 'config/node.yaml')]


def test_the_installed_solver_compiles_and_finds_the_paper_scenes_outside_a_checkout(prefix):
    """An install has no config/ beside its solver: the precompile runs build their scene from
    the schema's defaults (a worker of ``tensegrity compile`` runs from the root), and
    ``tensegrity paper`` runs the scenes the installed package finds."""
    r = subprocess.run([sys.executable, '-m', 'solver.simulate.precompile', 'chain1d'], cwd='/',
                       env=_env(), capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    code = ('from solver import paper\n'
            'from tensegrity_ros.io.share import find_data\n'
            'scenes = find_data("config/scenes/fb_column.yaml").parent\n'
            'print(paper.__file__)\n'
            'for v in paper.variants(("sym3d",), scenes):\n'
            '    print(v.scene)\n')
    r = subprocess.run([sys.executable, '-c', code], cwd='/', env=_env(), capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    module, *scenes = r.stdout.split()
    assert Path(module).is_relative_to(SITE)
    assert str(SHARE / 'config/scenes/paper_fb.yaml') in scenes
    assert str(SHARE / 'config/scenes/paper_rb.yaml') in scenes


def test_the_installed_node_runs_from_the_root_with_default_parameters(prefix):
    script = PREFIX / 'bin' / 'tensegrity_node'
    assert script.is_file()
    proc = subprocess.Popen([sys.executable, str(script)], cwd='/', env=_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines = []
    try:
        end = time.monotonic() + 600                    # a first compile for the new path
        while time.monotonic() < end:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line)
            if 'activated: stepping and publishing' in line:
                break
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            out, _ = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, _ = proc.communicate()
    text = ''.join(lines) + out
    assert any('activated: stepping and publishing' in x for x in lines), text[-3000:]
    scene = SHARE / 'config/scenes/fb_column.yaml'
    loading = [x for x in lines if 'loading the scene and compiling' in x]
    assert loading and str(scene) in loading[0], text[-3000:]    # said before the compile
    assert proc.returncode == 0 and 'Traceback' not in text, text[-3000:]
