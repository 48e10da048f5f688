"""The front figures at 1 m/s (docs/physics.md section 7.1): the front's arrivals at prisms 5
and 20 from the impacted end and its first peak at prism 20 change by less than 1 % when dt is
halved (with the contact resolution doubled), on both default columns, over 1 s. The peak
tracked at 0.5 s and over prisms 10-40 does not settle there: behind the front the response is
chaotic."""
from pathlib import Path

import math

import pytest

from solver.build.scene import Scene
from solver.simulate.runner import simulate

SCENES = Path(__file__).resolve().parents[1] / 'config' / 'scenes'
FRONT = ('front_speed_m_s', 'front_amplitude', 'front_arrival_s')


def _pulse(name, halved):
    scene = Scene.load(SCENES / f'{name}.yaml')
    sets = [('loading.impact.v0', 1.0), ('run.t_end', 1.0)]
    if halved:          # written out here, not taken from solver.simulate.convergence
        sets += [('integrator.dt', scene.integrator.dt / 2),
                 ('contact.resolution', 2 * scene.contact.resolution)]
    point = simulate(scene, sets)
    assert point.summary.to_json()['energy_balance_error'] < scene.divergence.energy_error
    return point.summary.to_json()['pulse']


@pytest.mark.parametrize('name', ['fb_column', 'rb_column'])
def test_front_figures_at_1_m_s_change_by_less_than_1_percent_when_dt_is_halved(name):
    base, halved = _pulse(name, False), _pulse(name, True)
    for k in FRONT:
        assert math.isfinite(base[k]) and math.isfinite(halved[k]), k
        assert abs(base[k] - halved[k]) <= 0.01 * max(abs(base[k]), abs(halved[k])), \
            (k, base[k], halved[k])
    # the front moves from prism 5 to prism 20 well after the impact, at a finite speed
    assert 0.0 < base['front_arrival_s'] < 1.0 and base['front_speed_m_s'] > 0.0
