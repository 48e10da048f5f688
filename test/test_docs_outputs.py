"""Docs that quote the product (issue 50, item 8): the target file sweeps.md lists, the topics of
interfaces.md section 4 and of mcap.md against the node's topic table and QoS, and the README's
examples writing under runs/."""
import re

import yaml

from docs_helpers import ROOT, text_of

DOCS = ROOT / 'docs'


def _indented_blocks(text):
    """The indented code blocks of a page, each as one text (indentation removed)."""
    blocks, cur = [], []
    for line in text.splitlines() + ['']:
        if line.startswith('    '):
            cur.append(line[4:])
        elif cur and line.strip():
            blocks.append('\n'.join(cur))
            cur = []
        elif cur:
            cur.append('')
    return blocks


def test_the_target_sweeps_md_lists_is_the_shipped_file():
    shipped = yaml.safe_load((ROOT / 'config' / 'paper' / 'fb_target.yaml').read_text())
    listed = [yaml.safe_load(b) for b in _indented_blocks(text_of(DOCS / 'sweeps.md'))
              if b.startswith('cases:')]
    assert shipped in listed
    text = text_of(DOCS / 'sweeps.md')
    words = {1: 'one', 2: 'two', 3: 'three', 4: 'four', 5: 'five'}
    assert f"{words[len(shipped['cases'])]} cases" in text


def test_interfaces_section_4_lists_every_topic_with_its_durability():
    from rclpy.qos import DurabilityPolicy
    from tensegrity_ros.msgs.style import TYPES
    from tensegrity_ros.node.qos import QOS, STRUCTURE_QOS
    text = text_of(DOCS / 'interfaces.md')
    section = text.split('## 4. ROS 2 node', 1)[1].split('\n## 5.', 1)[0]
    rows = dict(re.findall(r'^\| `([~/][^`]+)` \| (?:sub|pub), `([^`]+)`', section, re.M))
    assert rows == TYPES
    assert QOS.durability != DurabilityPolicy.TRANSIENT_LOCAL and 'volatile' in section
    assert STRUCTURE_QOS.durability == DurabilityPolicy.TRANSIENT_LOCAL
    assert 'except `~/structure`: reliable, transient-local' in section


def test_mcap_md_names_every_topic_a_log_can_hold():
    from tensegrity_ros.msgs.style import TYPES
    text = ' '.join(text_of(DOCS / 'mcap.md').split())
    part = text.split('What a log holds:', 1)[1].split('CDR-encoded', 1)[0]
    for key in TYPES:
        leaf = key.rsplit('/', 1)[1] if key.startswith('~/') else key
        if key.startswith('~/cmd/'):
            leaf = 'cmd/' + leaf
        assert leaf in part, key


def test_readme_examples_write_under_runs():
    for line in text_of(ROOT / 'README.md').splitlines():
        m = re.search(r'--out (\S+)', line)
        if m and line.startswith('    '):
            assert m.group(1).startswith('runs/'), line


def test_the_held_out_target_holds_the_figures_of_the_runs_it_names():
    """config/targets/heldout_fb.yaml (docs/sweeps.md): the figures of fb_column at radius
    0.0042 m, prestrain 0.003, to 0.55 s, rounded to 5 digits as the file says."""
    from solver.simulate.runner import simulate
    target = yaml.safe_load((ROOT / 'config' / 'targets' / 'heldout_fb.yaml').read_text())
    for case in target['cases']:
        pulse = simulate(ROOT / 'config' / 'scenes' / 'fb_column.yaml', [
            ('structure.radius', 0.0042), ('prestrain', 0.003), ('run.t_end', 0.55),
            *case['set'].items()]).summary.to_json()['pulse']
        for name, value in case['figures'].items():
            assert round(pulse[name.split('.', 1)[1]], 5) == value, name
