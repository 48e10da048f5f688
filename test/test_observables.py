"""The pulse tracker and strain measure against synthetic signals with known answers."""
import numpy as np
import pytest

from solver.observables import leading_peak, prism_strains, track_pulse


def _travelling_pulse(speed_prisms_s, amp, sigma, n=50, t_end=1.0, dt=0.005, tail=True):
    """Strain history (prism 0 at the clamped end, impact at prism n-1) of a Gaussian compression
    moving away from the impacted end, with a slower, smaller oscillating tail behind it."""
    times = np.arange(0, t_end + dt / 2, dt)
    k = np.arange(n)[::-1]                      # distance from the impacted end
    strain = np.zeros((len(times), n))
    for i, t in enumerate(times):
        c = speed_prisms_s * t
        strain[i] = -amp * np.exp(-0.5 * ((k - c) / sigma) ** 2)
        if tail:
            strain[i] += 0.3 * amp * np.sin(k - 0.5 * c) * (k < 0.5 * c)
    return times, strain


def test_tracker_recovers_speed_amplitude_and_width_of_a_known_pulse():
    h0 = 0.0062
    times, strain = _travelling_pulse(40.0, 0.054, sigma=1.2)
    p = track_pulse(times, strain, h0)
    assert p.speed_m_s == pytest.approx(40.0 * h0, rel=0.01)
    assert p.amplitude == pytest.approx(0.054, rel=0.01)
    # strain is sampled per prism: between prisms the sampled peak is at worst half a prism
    # off-centre
    sampled_low = 0.054 * np.exp(-0.5 * (0.5 / 1.2) ** 2)
    assert sampled_low - 1e-12 <= p.amplitude_min <= p.amplitude_max <= 0.054 + 1e-12
    # |eps| >= amp / 2 within +/- sigma sqrt(2 ln 2) = +/- 1.41 prisms of the centre at t = 0.5
    assert p.width_prisms == 3
    assert p.arrival_time_s == pytest.approx(10 / 40.0, abs=0.01)


def test_tracker_gives_nan_when_the_pulse_never_enters_the_window():
    times, strain = _travelling_pulse(5.0, 0.05, sigma=1.0, tail=False)   # reaches prism 5
    p = track_pulse(times, strain, 0.0062)
    assert np.isnan(p.speed_m_s) and np.isnan(p.amplitude_median)


def test_leading_peak_ignores_round_off_noise_and_picks_the_front():
    assert np.isnan(leading_peak(np.full(50, -1e-15))[0])
    eps = np.zeros(50)
    eps[5], eps[20] = -0.2, -0.1                 # a bigger pulse behind the leading one
    pos, e = leading_peak(eps)
    assert round(pos) == 20 and e == -0.1


def test_strain_of_a_uniformly_compressed_column():
    levels = np.arange(3 * 4).reshape(1, 4, 3)
    h = 0.9 * 0.0062
    x = np.zeros((12, 3))
    x[:, 2] = np.repeat(np.arange(4) * h, 3)
    assert np.allclose(prism_strains(x, levels, 0.0062), (h - 0.0062) / h)
