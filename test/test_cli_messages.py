"""Bad input of issue 50, item 6: one line on stderr naming the problem, exit code 2, nothing
written; and the text summary's ledger and strain lines."""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
FB = str(ROOT / 'config' / 'scenes' / 'fb_column.yaml')
LENS = str(ROOT / 'config' / 'scenes' / 'lens_focus.yaml')


def _cli(*args, cwd):
    env = dict(os.environ, PYTHONPATH=str(ROOT), ROS_DOMAIN_ID=str(150 + os.getpid() % 50),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    return subprocess.run([sys.executable, '-m', 'tensegrity_ros.cli', *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


def _one_line(res, *words):
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2, res.stderr
    assert len(lines) == 1 and lines[0].startswith('tensegrity: '), res.stderr
    assert 'Traceback' not in res.stderr
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]


def _listing(path):
    return sorted((str(p.relative_to(path)), p.read_bytes() if p.is_file() else None)
                  for p in path.rglob('*'))


@pytest.mark.parametrize('argv', [
    ['run', FB, '--out', 'taken'],
    ['run', FB, '--plot', '--out', 'taken/inside'],
    ['sweep', FB, '--grid', 'prestrain=0.001,0.002', '--t-end', '0.05', '--out', 'taken'],
    ['lens', LENS, '--focus', '0,0.05', '--medium-speed', '1', '--plot', '--out', 'taken'],
    ['demo', '--out', 'taken'],
])
def test_out_naming_an_existing_file_is_one_line(tmp_path, argv):
    (tmp_path / 'taken').write_text('keep me\n')
    before = _listing(tmp_path)
    _one_line(_cli(*argv, cwd=tmp_path), 'taken', 'is a file')
    assert _listing(tmp_path) == before


@pytest.mark.parametrize('content, words', [
    (None, ('missing.yaml', 'cannot read')),
    ('a: [b\n', ('params.yaml', 'not valid YAML')),
    ('- 1\n- 2\n', ('params.yaml', 'expected NODE: {ros__parameters:', 'got list')),
    ('tensegrity_sim:\n  ros__parameters:\n    - 1\n',
     ('params.yaml', 'tensegrity_sim/ros__parameters holds list')),
])
def test_a_missing_or_broken_params_file_is_one_line(tmp_path, content, words):
    name = 'missing.yaml' if content is None else 'params.yaml'
    if content is not None:
        (tmp_path / name).write_text(content)
    before = _listing(tmp_path)
    _one_line(_cli('node', '--ros-args', '--params-file', name, cwd=tmp_path), *words)
    assert _listing(tmp_path) == before


@pytest.mark.parametrize('argv, words', [
    (['demo', '--v0', 'nan'], ('--v0', 'nan')),
    (['demo', '--v0', '0.1,inf'], ('--v0', 'inf')),
    (['demo', '--v0', '11'], ('--v0', '11')),
    (['demo', '--prestrain', 'nan'], ('--prestrain', 'nan')),
])
def test_demo_with_a_velocity_that_is_not_a_number_is_one_line(tmp_path, argv, words):
    res = _cli(*argv, cwd=tmp_path)
    line = _one_line(res, *words)
    assert len(line) < 120 and 'compiling' not in res.stderr
    assert not (tmp_path / 'runs').exists()


def test_a_method_that_cannot_run_the_scene_is_refused_in_one_line(tmp_path):
    line = _one_line(_cli('run', FB, '--set', 'integrator=rattle', cwd=tmp_path), 'rattle')
    assert 'rk4_projected' in line.split('use', 1)[1]
    assert 'rattle' not in line.split('use', 1)[1]


def test_the_text_summary_prints_the_ledger_and_explains_large_strain(tmp_path):
    """At 1 m/s the leading pulse flattens prisms: the summary says what the strain measure is and
    gives the flattest prism's height, read here from the recorded positions (prism heights from
    the mean heights of the node levels, not the solver's strain)."""
    from solver.build.scene import Scene
    from solver.simulate.runner import simulate
    res = _cli('run', FB, '--v0', '1', '--t-end', '0.3', cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert 'energy ledger: balance error' in res.stdout and 'drift' not in res.stdout
    line = next(ln for ln in res.stdout.splitlines() if 'strain is (h - h0)/h' in ln)
    reported = float(line.split('h_min/h0 = ')[1].split()[0].rstrip(','))
    heights = []

    def setup(stack, scene, sim):
        levels = np.asarray(sim.network.levels)[0]          # column 0: node indices per level

        def frame(f):
            z = np.asarray(f.positions)[:, 2]
            heights.append(np.diff([z[lv].mean() for lv in levels]))
        return frame, None, None
    point = simulate(FB, [('loading.impact.v0', 1.0), ('run.t_end', 0.3)], setup=setup)
    h0 = Scene.load(FB).structure.h0
    flattest = min(float(np.min(np.abs(h))) for h in heights) / h0
    assert point.summary.to_json()['energy_balance_error'] < 1e-4
    assert reported == pytest.approx(flattest, rel=0.02)
    assert reported < 0.5

    quiet = _cli('run', FB, '--t-end', '0.3', cwd=tmp_path)       # 0.1 m/s: a few per cent
    assert quiet.returncode == 0 and 'strain is (h - h0)/h' not in quiet.stdout


def test_the_shipped_parameters_file_passes_the_check():
    """config/node.yaml (a wildcard namespace, the node, its ros__parameters) is not refused."""
    from tensegrity_ros.commands.inputs import check_params_files
    check_params_files(['-p', 'dt:=0.001', '--params-file', str(ROOT / 'config' / 'node.yaml')])
