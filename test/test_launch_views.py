"""The launch file and the views agree with the node (``ros2 launch``, RViz and Foxglove are not
installed here, so nothing is started): every launch argument that goes to the node is one of
its declared parameters with a default it accepts, the executable is an entry point of setup.py,
the RViz config and the parameters file it names are shipped and installed; every topic the RViz
config and the Foxglove layout name is one the node publishes, with a display or panel that
shows its type, and every message path of a plot names a field of that type."""
import ast
import json
import re
from pathlib import Path

import pytest
import yaml

from tensegrity_ros.msgs import style
from tensegrity_ros.node.params import DEFAULTS, ROS_NAMES, check_parameters

ROOT = Path(__file__).resolve().parents[1]
LAUNCH = ROOT / 'launch' / 'tensegrity.launch.py'
RVIZ = ROOT / 'config' / 'tensegrity.rviz'
FOXGLOVE = ROOT / 'config' / 'tensegrity.foxglove.json'
# the topics the node publishes, full name -> type (the default namespace)
TOPICS = {style.resolve_topic(k): t for k, t in style.TYPES.items() if '/cmd/' not in k}
RVIZ_TYPES = {'rviz_default_plugins/PointCloud2': 'sensor_msgs/msg/PointCloud2',
              'rviz_default_plugins/MarkerArray': 'visualization_msgs/msg/MarkerArray'}
FOXGLOVE_3D = {'sensor_msgs/msg/PointCloud2', 'visualization_msgs/msg/MarkerArray'}


def launch_constants():
    """The module-level constants of the launch file, read with ``ast`` (the ``launch`` package
    need not be installed)."""
    tree = ast.parse(LAUNCH.read_text())
    out = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and isinstance(node.targets[0], ast.Name):
            try:
                out[node.targets[0].id] = ast.literal_eval(node.value)
            except ValueError:          # NODE_ARGUMENTS holds type names: read their names
                out[node.targets[0].id] = {
                    ast.literal_eval(k): tuple(e.value if isinstance(e, ast.Constant)
                                               else ast.unparse(e) for e in v.elts)
                    for k, v in zip(node.value.keys, node.value.values)}
    return out, tree


def setup_entry_points():
    """``name -> module:function`` of setup.py's console scripts, read with ``ast``."""
    for node in ast.walk(ast.parse((ROOT / 'setup.py').read_text())):
        if isinstance(node, ast.Dict):
            for k, v in zip(node.keys, node.values):
                if isinstance(k, ast.Constant) and k.value == 'console_scripts':
                    return dict(s.replace(' ', '').split('=') for s in ast.literal_eval(v))
    raise AssertionError('setup.py has no console_scripts')


def setup_data_files():
    """Every file setup.py's data_files install, as paths relative to the checkout."""
    import glob as globmod
    text = (ROOT / 'setup.py').read_text()
    patterns = re.findall(r"glob\('([^']+)'\)", text)
    return {p for pat in patterns for p in globmod.glob(pat, root_dir=ROOT)}


def test_launch_arguments_are_node_parameters_with_accepted_defaults():
    c, _ = launch_constants()
    args = c['NODE_ARGUMENTS']
    assert {'scene_file', 'real_time_factor', 'record_mcap', 'record_rerun'} <= set(args)
    for name, (default, kind, text) in args.items():
        assert name in DEFAULTS or name in ROS_NAMES, f'{name} is not a parameter of the node'
        assert text
        if name in DEFAULTS:
            typed = {'str': str, 'float': float, 'bool': lambda s: s == 'true'}[kind](default)
            assert type(typed) is type(DEFAULTS[name]), name
            check_parameters(dict(DEFAULTS, **{name: typed}))        # a default it accepts
    assert {'namespace', 'params_file', 'rviz'} <= set(c['OTHER_ARGUMENTS'])
    assert not set(c['OTHER_ARGUMENTS']) & set(DEFAULTS)
    assert c['NODE_ARGUMENTS']['scene_file'][0] == DEFAULTS['scene_file']
    assert '/' + c['OTHER_ARGUMENTS']['namespace'][0] == style.NAMESPACE
    assert c['NODE_NAME'] == style.NODE_NAME


def test_launch_executable_config_and_files_are_shipped():
    c, tree = launch_constants()
    scripts = setup_entry_points()
    assert c['EXECUTABLE'] in scripts and scripts[c['EXECUTABLE']].endswith('node.node:main')
    assert c['PACKAGE'] == 'tensegrity_ros'
    installed = setup_data_files()
    for rel in (c['RVIZ_CONFIG'], 'config/node.yaml', 'launch/tensegrity.launch.py',
                'config/tensegrity.foxglove.json', 'config/paper/fb_target.yaml'):
        assert (ROOT / rel).is_file() and rel in installed, rel
    # the parameters file it defaults to is the node's: one node key, only its parameters
    params = yaml.safe_load((ROOT / 'config/node.yaml').read_text())
    (key, body), = params.items()
    assert key.endswith('/' + style.NODE_NAME) and set(body['ros__parameters']) <= set(DEFAULTS)
    names = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
    assert {'Node', 'DeclareLaunchArgument', 'IfCondition', 'FindPackageShare'} <= names


def test_the_launch_description_builds_where_launch_is_installed():
    pytest.importorskip('launch_ros')
    import importlib.util
    spec = importlib.util.spec_from_file_location('tensegrity_launch', LAUNCH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    desc = mod.generate_launch_description()
    declared = {a.name for a in desc.get_launch_arguments()}
    assert declared == set(mod.NODE_ARGUMENTS) | set(mod.OTHER_ARGUMENTS)


def rviz_displays(data):
    """Every display of an RViz config (groups opened), as dicts."""
    out = []

    def walk(displays):
        for d in displays or []:
            out.append(d)
            walk(d.get('Displays'))
    walk(data['Visualization Manager']['Displays'])
    return out


def test_rviz_topics_and_frame_are_the_node_s():
    data = yaml.safe_load(RVIZ.read_text())
    assert data['Visualization Manager']['Global Options']['Fixed Frame'] == style.FRAME_ID
    shown = {}
    for d in rviz_displays(data):
        if 'Topic' in d:
            topic = d['Topic']['Value']
            assert topic in TOPICS, f'{d["Name"]}: {topic} is not a topic of the node'
            assert RVIZ_TYPES.get(d['Class']) == TOPICS[topic], (d['Class'], TOPICS[topic])
            shown[d['Class']] = topic
    assert set(shown) == set(RVIZ_TYPES)              # a point cloud and the markers


def _strings(value):
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _strings(k)
            yield from _strings(v)
    elif isinstance(value, list):
        for v in value:
            yield from _strings(v)
    elif isinstance(value, str):
        yield value


def split_path(path):
    """``(topic, first field or None)`` of a Foxglove message path such as
    ``/tensegrity/tensegrity_sim/strain.data[0]``: the longest topic of the node it starts
    with; ``(None, None)`` when it names none."""
    for topic in sorted(TOPICS, key=len, reverse=True):
        if path == topic:
            return topic, None
        if path.startswith(topic) and path[len(topic)] in '.{[':
            field = re.match(r'\.(\w+)', path[len(topic):])
            return topic, field.group(1) if field else None
    return None, None


def _fields(type_name):
    import importlib
    pkg, _, name = type_name.split('/')
    cls = getattr(importlib.import_module(f'{pkg}.msg'), name)
    return cls.get_fields_and_field_types()


def test_foxglove_layout_names_only_the_node_s_topics_and_fields():
    pytest.importorskip('std_msgs')
    layout = json.loads(FOXGLOVE.read_text())
    panels = layout['configById']
    named = [s for s in _strings(panels) if s.startswith('/')]
    assert len(named) >= 8
    for s in named:
        topic, field = split_path(s)
        assert topic is not None, f'{s} names no topic of the node'
        if field is not None:
            assert field in _fields(TOPICS[topic]), f'{s}: no field {field} in {TOPICS[topic]}'
    for panel, config in panels.items():
        kind = panel.split('!')[0]
        if kind == '3D':
            assert config['followTf'] == style.FRAME_ID
            assert {TOPICS[t] for t in config['topics']} == FOXGLOVE_3D
        elif kind == 'Plot':
            for p in config['paths']:
                topic, field = split_path(p['value'])
                assert field is not None and 'double' in _fields(TOPICS[topic])[field]
        elif kind.startswith('Diagnostic'):
            assert TOPICS[config['topicToRender']] == 'diagnostic_msgs/msg/DiagnosticArray'
    # every panel the layout places is configured, and every configured panel placed
    placed = {s for s in _strings(layout['layout']) if '!' in s}
    assert placed == set(panels)


def test_the_checks_catch_a_wrong_topic():
    assert split_path('/tensegrity/tensegrity_sim/strains.data[0]') == (None, None)
    assert split_path('/tensegrity/tensegrity_sim/strain.data[3]') == (
        '/tensegrity/tensegrity_sim/strain', 'data')
    assert split_path('/clock.clock') == ('/clock', 'clock')
