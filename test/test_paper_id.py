"""The identified model of the paper (config/scenes/paper_fb.yaml, paper_rb.yaml) and the study
that produced it (bench/paper_id.py, docs/paper.md)."""
import math
from pathlib import Path

import pytest

from bench import paper_id
from solver.build.scene import Scene

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / 'config' / 'scenes'


def _leaves(data, prefix=''):
    for k, v in data.items():
        if isinstance(v, dict):
            yield from _leaves(v, prefix + k + '.')
        else:
            yield prefix + k, v


def test_paper_rb_differs_from_paper_fb_only_in_the_bases():
    """The rigid-base prediction uses the choices identified on the flexible-base column: the two
    scenes may differ in the bases (and their name and description), in nothing else."""
    fb = dict(_leaves(Scene.load(SCENES / 'paper_fb.yaml').data))
    rb = dict(_leaves(Scene.load(SCENES / 'paper_rb.yaml').data))
    differ = {k for k in fb if fb[k] != rb[k]}
    assert fb['structure.bases'] == 'flexible' and rb['structure.bases'] == 'rigid'
    assert differ <= {'structure.bases', 'name', 'description'}, differ


def test_the_identified_scene_is_a_member_of_the_stated_family():
    """paper_fb.yaml departs from the plain reading (fb_column.yaml) only in keys of the family
    the study searches: no other number is changed."""
    changed = set(paper_id.identified_overrides())
    assert changed, 'paper_fb.yaml is the plain reading'
    assert changed <= set(paper_id.FAMILY), changed


def test_residuals_are_relative_errors_of_the_paper_figures():
    """The study's error measure on hand-made figures: exact paper figures give 0; a figure off
    by 10 % gives 10 % in its entry; a missing figure counts as a large error."""
    exact = {v0: {'pulse.amplitude': a, 'pulse.speed_m_s': s, paper_id.WIDTH: w}
             for v0, (a, s, w) in paper_id.PAPER.items()}
    err, parts = paper_id.residuals(exact, 'pulse.speed_m_s')
    assert err == 0.0 and len(parts) == 6
    off = {v0: dict(f) for v0, f in exact.items()}
    off[0.15]['pulse.amplitude'] = 0.085 * 1.1
    err, parts = paper_id.residuals(off, 'pulse.speed_m_s')
    assert dict((n, e) for n, e, _ in parts)['amplitude at 0.15'] == pytest.approx(0.1)
    assert err == pytest.approx(math.sqrt(0.01 / (5 + paper_id.WIDTH_WEIGHT)))
    del off[0.1]
    assert paper_id.residuals(off, 'pulse.speed_m_s')[0] > 1.0


def test_docs_paper_names_the_command_that_regenerates_it():
    text = (ROOT / 'docs' / 'paper.md').read_text()
    assert 'python -m bench.paper_id' in text


def test_no_bar_radius_of_the_family_touches_at_rest():
    """The family's bars fit in every prism of the family at rest: twice the largest bar radius
    is below the smallest distance between two bars that can touch, at the smallest base radius
    (the closest bars), found here by sampling the segments of the first prisms densely (the
    prisms are identical at rest) and checked against paper_id.rest_gap."""
    import numpy as np

    from solver.build import structures
    from solver.build.scene import Scene
    r = min(paper_id.FAMILY['structure.radius'])
    net = structures.build_network(Scene.load(paper_id.FB).with_overrides(
        [('structure.radius', r)]))
    x = np.asarray(net.x0)
    lev = np.asarray(net.levels)[0]
    bars = [(a, b) for a, b in zip(net.bar_a, net.bar_b)
            if {int(a), int(b)} <= set(lev[:3].ravel().tolist())]
    s = np.linspace(0.0, 1.0, 401)[:, None]
    best = np.inf
    for i, (a, b) in enumerate(bars):
        p = x[a] + s * (x[b] - x[a])
        for c, d in bars[i + 1:]:
            if {int(a), int(b)} & {int(c), int(d)}:
                continue                                   # bars sharing a joint
            q = x[c] + s * (x[d] - x[c])
            best = min(best, np.min(np.linalg.norm(p[:, None] - q[None], axis=2)))
    gap = paper_id.rest_gap([('structure.radius', r)])
    assert gap == pytest.approx(best, abs=2e-6)           # sampling: 1/400 of a bar
    assert 2 * max(paper_id.FAMILY['materials.bar_radius']) < gap


@pytest.mark.parametrize('reading', ['snapshot', 'paper'])
def test_the_fit_target_reads_the_speeds_as_asked(tmp_path, reading):
    """--speed: the target's speed figures are the summary's figure of that reading, and
    tensegrity fit accepts the file."""
    from tensegrity_ros.studies import fit as fitmod
    path = paper_id.write_target(tmp_path / 't.yaml', paper_id.SPEEDS[reading])
    cases = fitmod.load_target(path)
    speeds = [c.figures[paper_id.SPEEDS[reading]] for c in cases
              if paper_id.SPEEDS[reading] in c.figures]
    assert speeds == [0.248, 0.372]
    assert all('pulse.speed_m_s' not in c.figures for c in cases)
