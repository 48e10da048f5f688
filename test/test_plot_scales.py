"""``tensegrity run --plot`` after a crushing impact (issue 50): a 0.15 pulse beside a prism at
-31.5 keeps a visible share of the colour scale and of the snapshot axis; a run of small strains
keeps linear scales."""
from types import SimpleNamespace

import numpy as np

from tensegrity_ros.studies.plots import strain_wave_figure


def _record(peak_crush):
    times = np.linspace(0.0, 1.0, 201)
    strain = np.zeros((times.size, 1, 20))
    strain[:, 0, 18] = peak_crush                 # a crushed prism near the struck end
    strain[100:, 0, 5] = -0.15                    # a later pulse of 0.15
    return SimpleNamespace(times=times, strain=strain)


def test_a_small_pulse_after_a_crush_keeps_a_share_of_the_colour_scale():
    import matplotlib.pyplot as plt
    fig = strain_wave_figure(_record(-31.5))
    heat, snapshots = fig.axes[1].images[0], fig.axes[0]
    norm = heat.norm
    # on a linear scale of +-31.5 the pulse would move the colour by 0.15 / 63 = 0.24 % of the
    # map; on the symmetric-log scale it moves it by more than a quarter of the half map
    assert abs(norm(-0.15) - norm(0.0)) > 0.25 * abs(norm(-31.5) - norm(0.0))
    assert snapshots.get_yscale() == 'symlog'
    plt.close(fig)
    fig = strain_wave_figure(_record(-0.05))
    assert fig.axes[0].get_yscale() == 'linear'
    norm = fig.axes[1].images[0].norm                 # linear over +-0.15, the largest |strain|
    assert [float(norm(v)) for v in (-0.15, -0.075, 0.0)] == [0.0, 0.25, 0.5]
    plt.close(fig)
