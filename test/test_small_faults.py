"""Faults a new user meets: each gives one message naming the problem (or, for the plot, a
picture that shows what it says)."""
import ast
import re

import numpy as np
import pytest

from mcap_helpers import ROOT
from solver.build.scene import Scene, SceneError

SCENES = ROOT / 'config' / 'scenes'


@pytest.mark.parametrize('text', ['', '\n\n', '# only a comment\n'])
def test_an_empty_scene_file_is_an_error_naming_it(tmp_path, text):
    path = tmp_path / 'empty.yaml'
    path.write_text(text)
    with pytest.raises(SceneError, match=re.escape(str(path)) + '.*empty'):
        Scene.load(path)


def test_cli_refuses_an_empty_scene(tmp_path, capsys):
    from tensegrity_ros.cli import main
    path = tmp_path / 'empty.yaml'
    path.write_text('')
    assert main(['run', str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and str(path) in err and 'empty' in err


def test_a_bad_set_key_lists_the_valid_keys_as_a_bad_yaml_key_does(tmp_path):
    scene = Scene.load(SCENES / 'prism.yaml')
    with pytest.raises(SceneError) as from_set:
        scene.with_overrides(['integrator.metod=rk4'])
    bad = scene.data
    bad['integrator']['metod'] = 'rk4'
    with pytest.raises(SceneError) as from_yaml:
        Scene(bad)
    assert str(from_set.value) == str(from_yaml.value)
    valid = sorted(Scene.load(SCENES / 'prism.yaml')['integrator'])
    assert str(from_set.value) == f'integrator.metod: unknown key (valid here: {", ".join(valid)})'
    with pytest.raises(SceneError, match='valid here: .*integrator'):
        scene.with_overrides(['integratr.dt=1e-4'])


def test_an_empty_mcap_says_so(tmp_path):
    from tensegrity_ros.io.mcap_reader import LogError, load_run
    path = tmp_path / 'empty.mcap'
    path.write_bytes(b'')
    with pytest.raises(LogError) as err:
        load_run(path)
    assert '()' not in str(err.value) and 'empty' in str(err.value)


def test_to_rerun_of_a_truncated_log_says_it_was_cut_short(tmp_path, capsys):
    pytest.importorskip('rerun')
    from record_helpers import record_long
    from tensegrity_ros.cli import main
    path = tmp_path / 'full.mcap'
    record_long(path, 200)
    data = path.read_bytes()
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(data[:len(data) // 2])
    assert main(['replay', str(path), '--to-rerun', str(tmp_path / 'full.rrd')]) == 0
    assert 'cut short' not in capsys.readouterr().out
    assert main(['replay', str(cut), '--to-rerun', str(tmp_path / 'cut.rrd')]) == 0
    out = capsys.readouterr().out
    assert 'cut short' in out and out.count('\n') == 1


def test_setup_names_no_switch_it_does_not_implement():
    """The ROS wheels are an extra only: a plain install (users with a ROS distribution) does
    not pull them, and setup.py mentions no environment switch."""
    text = (ROOT / 'setup.py').read_text()
    assert 'TENSEGRITY_NO_ROS_WHEELS' not in text and 'environ' not in text
    tree = ast.parse(text)
    lists = {t.id: ast.literal_eval(n.value) for n in tree.body if isinstance(n, ast.Assign)
             for t in n.targets if isinstance(t, ast.Name) and isinstance(n.value, ast.List)}
    assert lists['ROS_WHEELS'] and all(w.startswith('ros-') for w in lists['ROS_WHEELS'])
    assert not any(c.startswith('ros-') for c in lists['CORE'])


def _fake_record(n_prisms, t_end=0.3):
    from types import SimpleNamespace
    times = np.arange(0.0, t_end + 1e-9, 0.01)
    strain = -0.01 * np.exp(-((np.arange(n_prisms)[None, :] - 20 * times[:, None]) ** 2))
    return SimpleNamespace(times=times, strain=strain[:, None, :])


@pytest.mark.parametrize('n_prisms', [1, 5])
def test_strain_plot_shows_its_lines_labels_and_whole_prisms(n_prisms):
    from tensegrity_ros.studies.plots import strain_wave_figure
    fig = strain_wave_figure(_fake_record(n_prisms), 'x')
    ax1, ax2 = fig.axes[:2]
    lines = ax1.get_lines()
    assert lines and ax1.get_legend() is not None
    for line in lines:                                  # a line of one point needs a marker
        assert len(line.get_xdata()) > 1 or line.get_marker() not in (None, '', 'None')
    label = ax1.get_xlabel()
    assert label.count(' 1 ') + label.count('(1 ') <= 1     # not "1 = ..., 1 = ..."
    ticks = [t for t in ax2.get_yticks() if ax2.get_ylim()[0] <= t <= ax2.get_ylim()[1]]
    assert ticks and all(float(t).is_integer() for t in ticks)
    assert all(1 <= t <= n_prisms for t in ticks)
    import matplotlib.pyplot as plt
    plt.close(fig)


def test_strain_plot_marks_the_front_at_its_stations():
    """A compression of 5 % moving at 40 prisms per second away from the impacted end of 50
    prisms: the heat map joins its arrivals at prisms 5 and 20 from that end (plot prisms 45 and
    30) and names the speed; a pulse below the front's level gets no mark."""
    from types import SimpleNamespace
    from tensegrity_ros.studies.plots import strain_wave_figure
    import matplotlib.pyplot as plt
    times = np.arange(0.0, 1.0 + 1e-9, 0.005)
    from_impact = np.arange(50)[None, :] - 40 * times[:, None]
    strain = (-0.05 * np.exp(-0.5 * (from_impact / 1.2) ** 2))[:, ::-1]
    fig = strain_wave_figure(SimpleNamespace(times=times, strain=strain[:, None, :]))
    front = [ln for ln in fig.axes[1].get_lines() if 'front' in ln.get_label()]
    assert len(front) == 1 and list(front[0].get_ydata()) == [45, 30]
    t5, t20 = front[0].get_xdata()
    assert t20 - t5 == pytest.approx(15 / 40, rel=1e-3)
    assert '40.0 prisms/s' in front[0].get_label()
    plt.close(fig)
    weak = strain_wave_figure(SimpleNamespace(times=times, strain=0.5 * strain[:, None, :]))
    assert not [ln for ln in weak.axes[1].get_lines() if 'front' in ln.get_label()]
    plt.close(weak)


def test_run_plot_of_the_prism_scene(tmp_path):
    from tensegrity_ros.cli import main
    assert main(['run', str(SCENES / 'prism.yaml'), '--plot', '--out', str(tmp_path)]) == 0
    assert (tmp_path / 'strain_wave.png').stat().st_size > 1000


def test_package_xml_declares_every_run_time_dependency():
    """Every requirement of setup.py's CORE has an exec_depend key in package.xml (rosdep's key
    names), except rerun-sdk, dask, distributed and pyarrow, which docs/interfaces.md installs
    with pip (pinned as in setup.py), and mcap, which mcap-ros2-support brings."""
    import xml.etree.ElementTree as ET
    keys = {e.text for e in ET.parse(ROOT / 'package.xml').getroot().iter('exec_depend')}
    tree = ast.parse((ROOT / 'setup.py').read_text())
    core = [ast.literal_eval(n.value) for n in tree.body if isinstance(n, ast.Assign)
            and any(getattr(t, 'id', '') == 'CORE' for t in n.targets)][0]
    key_of = {'numpy': 'python3-numpy', 'numba': 'python3-numba', 'scipy': 'python3-scipy',
              'pyyaml': 'python3-yaml', 'matplotlib': 'python3-matplotlib',
              'tqdm': 'python3-tqdm', 'mcap-ros2-support': 'mcap-ros2-support',
              'mcap': 'mcap-ros2-support', 'rerun-sdk': None,
              # sweeps and fits only (not the node): pip, as docs/interfaces.md section 1 says
              'dask': None, 'distributed': None, 'pyarrow': None}
    for req in core:
        name = req.split('==')[0]
        assert name in key_of, f'{name}: no rosdep key chosen'
        if key_of[name]:
            assert key_of[name] in keys, f'{name}: {key_of[name]} missing from package.xml'
    install = (ROOT / 'docs' / 'interfaces.md').read_text()
    for name, key in key_of.items():
        if key is None:
            pin = next(r for r in core if r.split('==')[0] == name)
            assert pin in install, f'{name}: docs/interfaces.md does not say how to install it'
