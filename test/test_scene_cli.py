"""Scene validation, the `tensegrity run` command line, and the one-way layering of the
packages."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from solver.build.scene import Scene, SceneError

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / 'config' / 'scenes'


@pytest.mark.parametrize('name', ['prism', 'fb_column', 'rb_column', 'fb_train'])
def test_shipped_scenes_load(name):
    scene = Scene.load(SCENES / f'{name}.yaml')
    assert scene.name == name


@pytest.mark.parametrize('raw,key', [
    ({'structur': {}}, 'structur'),
    ({'structure': {'n_prism': 3}}, 'structure.n_prism'),
    ({'structure': {'n_prisms': 'many'}}, 'structure.n_prisms'),
    ({'structure': {'n_prisms': 2.5}}, 'structure.n_prisms'),
    ({'structure': {'bases': 'wobbly'}}, 'structure.bases'),
    ({'structure': {'builder': 'dome'}}, 'structure.builder'),
    ({'prestrain': -0.1}, 'prestrain'),
    ({'prestrain': float('nan')}, 'prestrain'),
    ({'integrator': {'dt': 0}}, 'integrator.dt'),
    ({'integrator': {'land_on_kinks': 'yes'}}, 'integrator.land_on_kinks'),
    ({'model': 'quantum'}, 'model'),
    ({'loading': {'impact': {'columns': [3]}}}, 'loading.impact.columns'),
    ({'run': {'output_dt': 1e-5}}, 'run.output_dt'),
    ([1, 2], 'scene'),
])
def test_bad_scene_values_name_the_key(raw, key):
    with pytest.raises(SceneError) as err:
        Scene(raw)
    assert str(err.value).startswith(key)


def test_overrides_parse_values_and_reject_unknown_keys():
    scene = Scene.load(SCENES / 'fb_column.yaml')
    s2 = scene.with_overrides(['integrator.dt=2.5e-4', 'structure.bases=rigid',
                               'integrator=rk4_projected'])
    assert s2['integrator.dt'] == 2.5e-4 and s2['structure.bases'] == 'rigid'
    assert scene['integrator.dt'] == Scene.load(SCENES / 'fb_column.yaml')['integrator.dt']
    with pytest.raises(SceneError, match='integrator.dtt'):
        scene.with_overrides(['integrator.dtt=1'])
    with pytest.raises(SceneError, match='expected KEY=VALUE'):
        scene.with_overrides(['dt'])


def test_bad_yaml_names_the_file_and_line(tmp_path):
    path = tmp_path / 'bad.yaml'
    path.write_text('structure:\n  n_prisms: [1,\n')
    with pytest.raises(SceneError, match='bad.yaml: line'):
        Scene.load(path)


def _cli(*args, cwd=ROOT):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, '-m', 'tensegrity_ros.cli', *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


def test_run_json_summary_has_the_documented_keys(tmp_path):
    res = _cli('run', str(SCENES / 'prism.yaml'), '--t-end', '0.05', '--json', '--out',
               str(tmp_path))
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    for key in ('scene', 'model', 'integrator', 'dt', 't_end', 'n_nodes', 'n_bars', 'n_cables',
                'steps', 'wall_time_s', 'real_time_factor', 'energy_drift_rel',
                'constraint_error_rel', 'pulse', 'outputs', 'impacts', 'energy_work_J',
                'energy_balance_error', 'bar_contact', 'contacts_met'):
        assert key in out
    assert out['n_nodes'] == 6 and out['n_bars'] == 3 and out['n_cables'] == 9
    assert out['t_end'] == pytest.approx(0.05)
    assert json.loads((tmp_path / 'summary.json').read_text())['scene'] == 'prism'


def _run_json(capsys, *args):
    from tensegrity_ros import cli
    capsys.readouterr()
    assert cli.main(['run', *args, '--json']) == 0
    return json.loads(capsys.readouterr().out)


def test_run_applies_a_train_of_impacts_and_reports_the_ledger(capsys):
    """5 impacts of 0.1 m/s every 20 ms on a 10-prism FB column: each at its time, their work
    is the ledger's, the balance error is small; the same train as times and velocities gives the
    same summary; the text output prints the balance error."""
    fb, short = str(SCENES / 'fb_column.yaml'), ['--set', 'structure.n_prisms=10', '--t-end',
                                                   '0.1']
    out = _run_json(capsys, fb, *short, '--set', 'loading.impact.period=0.02', '--set',
                    'loading.impact.count=5')
    assert [i['t_s'] for i in out['impacts']] == pytest.approx([0, 0.02, 0.04, 0.06, 0.08],
                                                               abs=1e-12)
    assert [i['v0_m_s'] for i in out['impacts']] == [0.1] * 5
    assert sum(i['work_J'] for i in out['impacts']) == pytest.approx(out['energy_work_J'],
                                                                     rel=1e-12)
    assert 0 <= out['energy_balance_error'] < 1e-4 and out['bar_contact'] == 'hertz'
    listed = _run_json(capsys, fb, *short, '--set', 'loading.impact.times=[0, .02, .04, .06, .08]',
                       '--set', 'loading.impact.velocities=[0.1, 0.1, 0.1, 0.1, 0.1]')
    timing = ('wall_time_s', 'real_time_factor')
    assert {k: v for k, v in listed.items() if k not in timing} == \
        {k: v for k, v in out.items() if k not in timing}
    from tensegrity_ros import cli
    assert cli.main(['run', fb, *short, '--set', 'loading.impact.count=5', '--set',
                     'loading.impact.period=0.02']) == 0
    text = capsys.readouterr().out
    assert f"energy ledger: balance error {out['energy_balance_error']:.2e} (largest" in text
    assert 'drift' not in text          # a train's energy grows by its work: not an error
    assert 'in 5 impact(s)' in text


def test_a_run_too_short_for_a_pulse_gives_strict_json_with_nulls(tmp_path):
    """No pulse is found in 5 ms of the FB column: its figures are null (JSON has no NaN) in the
    printed summary and in summary.json, and the text output says so."""
    def strict(text):
        def bad(name):
            raise AssertionError(f'{name} in the JSON')
        return json.loads(text, parse_constant=bad)
    res = _cli('run', str(SCENES / 'fb_column.yaml'), '--t-end', '0.005', '--json', '--out',
               str(tmp_path))
    assert res.returncode == 0, res.stderr
    out = strict(res.stdout)
    assert out['pulse']['amplitude'] is None and out['pulse']['speed_m_s'] is None
    assert strict((tmp_path / 'summary.json').read_text())['pulse']['amplitude'] is None
    res = _cli('run', str(SCENES / 'fb_column.yaml'), '--t-end', '0.005')
    assert res.returncode == 0 and 'pulse: none found by t = 0.005 s' in res.stdout


@pytest.mark.parametrize('v0,t_end,reason', [
    (2.0, 0.35, 'it reached the clamped end at t = '),   # RB at 2 m/s: the end by 0.27 s
    (0.3, 0.3, 'the run ends at t = 0.3 s')])
def test_a_pulse_without_an_amplitude_at_t_ref_is_still_reported(capsys, v0, t_end, reason):
    """The amplitude is read at 0.5 s. A run that ends before, or whose pulse reaches the clamped
    end before, has no amplitude but a speed and a median amplitude over the window: the text
    summary gives those and says why the amplitude is missing, not that no pulse was found."""
    args = [str(SCENES / 'rb_column.yaml'), '--v0', str(v0), '--t-end', str(t_end)]
    p = _run_json(capsys, *args)['pulse']
    assert p['amplitude'] is None and p['speed_m_s'] > 0 and p['amplitude_median'] > 0
    from tensegrity_ros import cli
    assert cli.main(['run', *args]) == 0
    line = [ln for ln in capsys.readouterr().out.splitlines() if 'pulse:' in ln]
    assert len(line) == 1 and 'none found' not in line[0], line
    assert f"speed {p['speed_m_s']:.3f} m/s" in line[0]
    assert f"median amplitude {p['amplitude_median']:.4f}" in line[0]
    assert reason in line[0]
    if v0 == 2.0:
        assert p['arrival_end_s'] < 0.5


def test_a_run_where_bars_touched_says_so_and_points_to_the_check(capsys):
    """``contacts_met`` in the summary counts the force evaluations that met a contact (the
    simulation's own counter); the text output names it and points to ``--convergence``, and
    says nothing where no contact acted (the paper's 0.1 m/s)."""
    from solver.simulate.runner import simulate
    from tensegrity_ros import cli
    rb = [str(SCENES / 'rb_column.yaml'), '--v0', '0.3', '--t-end', '0.3']
    met = _run_json(capsys, *rb)['contacts_met']
    assert met > 0
    assert met == simulate(rb[0], ['loading.impact.v0=0.3', 'run.t_end=0.3']).sim.contacts_met
    assert cli.main(['run', *rb]) == 0
    assert f'contact: bars touched in {met} force evaluations' in capsys.readouterr().out
    fb = [str(SCENES / 'fb_column.yaml'), '--t-end', '0.1']
    assert _run_json(capsys, *fb)['contacts_met'] == 0
    assert cli.main(['run', *fb]) == 0
    assert 'contact:' not in capsys.readouterr().out


@pytest.mark.parametrize('args,needle', [
    (('run', 'no/such/scene.yaml'), 'cannot read scene file'),
    (('run', str(SCENES / 'prism.yaml'), '--set', 'integrator.dt=-1'), 'integrator.dt'),
    (('run', str(SCENES / 'prism.yaml'), '--set', 'integrator=euler'), 'euler'),
    (('run', str(SCENES / 'prism.yaml'), '--prestrain', '2'), 'prestrain'),
    (('run', str(SCENES / 'prism.yaml'), '--set', 'integrator.dt=3e-4'), 'whole multiple'),
    (('run', str(SCENES / 'fb_train.yaml'), '--t-end', '0.5'), 'loading.impact.period: the last'),
    (('run', str(SCENES / 'fb_column.yaml'), '--set', 'loading.impact.times=[0, 0.1]', '--set',
      'loading.impact.velocities=[0.1]'), 'loading.impact.velocities'),
])
def test_user_errors_are_one_line_without_traceback(args, needle):
    res = _cli(*args)
    assert res.returncode != 0
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], res.stderr
    assert 'Traceback' not in res.stderr


@pytest.mark.parametrize('args,needle', [
    (('run', str(SCENES / 'prism.yaml'), '--v0', 'abc'), "argument --v0: invalid float value"),
    (('lens', str(SCENES / 'lens_focus.yaml'), '--focus', '0.08,0.06'), '--medium-speed'),
    (('demo', '--domain-id', 'x'), 'argument --domain-id: invalid int value'),
    (('runx',), "invalid choice: 'runx'"),
    (('bench', '--bad-option'), 'unrecognized arguments: --bad-option'),
])
def test_argparse_errors_take_the_one_line_form_exit_2(args, needle):
    """argparse's own errors (a value of the wrong type, a missing option, an unknown command)
    read like the others: one line, ``tensegrity:`` first, exit code 2, no usage block."""
    res = _cli(*args)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('tensegrity: ') and needle in lines[0], \
        res.stderr
    assert '--help' in lines[0]


def test_solver_imports_without_ros_mcap_or_rerun():
    code = ('import sys\n'
            'for m in ("rclpy", "mcap", "mcap_ros2", "rerun"):\n'
            '    sys.modules[m] = None\n'
            'import pkgutil, importlib, solver\n'
            'for mod in pkgutil.iter_modules(solver.__path__):\n'
            '    importlib.import_module("solver." + mod.name)\n')
    res = subprocess.run([sys.executable, '-c', code], cwd=ROOT, capture_output=True, text=True,
                         env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=300)
    assert res.returncode == 0, res.stderr


def test_typed_sections_have_exactly_the_keys_of_the_defaults():
    """Every section record (solver/build/sections.py) has the keys of its section of
    DEFAULTS, no more and no fewer, and a loaded scene's records hold the file's values."""
    from dataclasses import fields

    from solver.build import sections
    from solver.build.scene import DEFAULTS, STRUCTURE_DEFAULTS

    def names(cls):
        return {f.name for f in fields(cls)}
    for name, cls in sections.SECTIONS.items():
        assert names(cls) == set(DEFAULTS[name]), name
    for builder, cls in sections.STRUCTURES.items():
        assert names(cls) == set(STRUCTURE_DEFAULTS[builder]), builder
    assert names(sections.Loading) == set(DEFAULTS['loading'])
    assert names(sections.Impact) == set(DEFAULTS['loading']['impact'])
    scene = Scene.load(SCENES / 'fb_column.yaml').with_overrides(
        ['run.t_end=0.7', 'loading.impact.columns=[0]', 'structure.n_prisms=7'])
    assert scene.run.t_end == 0.7 == scene['run.t_end']
    assert scene.loading.impact.columns == (0,) and scene.structure.n_prisms == 7
    with pytest.raises(AttributeError):
        scene.run.t_ned
    with pytest.raises(Exception):
        scene.run.t_end = 1.0                 # frozen: a scene is changed by with_overrides
