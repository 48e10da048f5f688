"""The pulse tracker and strain measure against synthetic signals with known answers."""
from pathlib import Path

import numpy as np
import pytest

from solver.analysis.observables import leading_peak, prism_strains, track_pulse

ROOT_SCENES = Path(__file__).resolve().parents[1] / 'config' / 'scenes'


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


# -- interpolated peak and the pulse measures, on a sech^2 pulse with known answers ---------------
def _sech2_history(c, amp, w, n=50, dt=0.007, t_end=1.4, modulation=None):
    """Strain history (prism 0 at the clamped end, impact at prism n-1) of a compression
    ``-amp(t) sech^2((k - c t) / w)`` moving ``c`` prisms/s away from the impacted end (k =
    prisms from it); output every ``dt`` s, which puts t = 0.5 s between two frames."""
    times = np.arange(0.0, t_end, dt)
    k = np.arange(n)[::-1].astype(float)
    strain = np.zeros((len(times), n))
    for i, t in enumerate(times):
        a = amp if modulation is None else amp * modulation(t)
        strain[i] = -a / np.cosh((k - c * t) / w) ** 2
    return times, strain


def test_pulse_measures_of_a_sech2_pulse_match_their_closed_forms():
    from solver.analysis.observables import first_passage
    h0, c, amp, w = 0.0062, 41.3, 0.054, 4.0
    times, strain = _sech2_history(c, amp, w)
    p = first_passage(times, strain, h0)
    assert 0.5 not in times
    # amplitude at t = 0.5 s between frames, the peak between prisms (20.65 prisms travelled);
    # a parabola through three prisms of a pulse 4 prisms wide is within 0.3 % of its top
    assert p.amplitude == pytest.approx(amp, rel=3e-3)
    assert p.amplitude_passage_max == pytest.approx(amp, rel=3e-3)
    # snapshot: position at t_ref / t_ref; slope; arrival at the clamped end (n - 2 prisms)
    assert p.speed_snapshot_m_s == pytest.approx(c * h0, rel=2e-3)
    assert p.speed_m_s == pytest.approx(c * h0, rel=2e-3)
    assert p.arrival_end_s == pytest.approx(48 / c, abs=1e-3)
    assert p.speed_arrival_m_s == pytest.approx(c * h0, rel=2e-3)
    # sech^2(x / w) = f at x = w acosh(1 / sqrt(f)): width 2 w acosh(sqrt(2)) at half maximum,
    # 2 w acosh(sqrt(10)) at 10 % (linear interpolation between prisms: within 0.1 prism)
    assert p.width_half_prisms == pytest.approx(2 * w * np.arccosh(np.sqrt(2)), abs=0.1)
    assert p.width_10_prisms == pytest.approx(2 * w * np.arccosh(np.sqrt(10)), abs=0.1)


def test_maximum_over_the_first_passage_falls_between_frames():
    from solver.analysis.observables import first_passage
    t_star = 0.4431                               # between frames (dt = 0.007)

    def modulation(t):
        return 1.0 + 0.3 * np.exp(-((t - t_star) / 0.12) ** 2)

    times, strain = _sech2_history(37.0, 0.05, 4.0, modulation=modulation)
    p = first_passage(times, strain, 0.0062)
    assert p.amplitude_passage_max == pytest.approx(0.05 * 1.3, rel=3e-3)
    assert p.amplitude == pytest.approx(0.05 * modulation(0.5), rel=3e-3)
    sampled = np.abs(strain).max(axis=1).max()
    assert p.amplitude_passage_max > sampled      # above every sampled value: interpolated


def test_peak_between_prisms_is_interpolated_along_the_column():
    # a parabola-shaped peak: the interpolation is exact
    k = np.arange(20, dtype=float)
    eps = -np.maximum(0.0, 0.04 - 0.002 * (k - 7.3) ** 2)
    pos, e = leading_peak(eps)
    assert pos == pytest.approx(7.3, abs=1e-12) and e == pytest.approx(-0.04, rel=1e-12)


def test_a_peak_reflected_short_of_the_end_does_not_enter_the_speed_fit():
    """A pulse at 90 prisms/s whose tracked peak turns back at 47.5 prisms from the impact (the
    clamped end reflects it before the tracker sees it reach n - 2) and comes back through the
    10-40 window: only the first passage is fitted, so the slope is the forward speed; counting
    the way back too would give about half of it."""
    from solver.analysis.observables import first_passage
    h0, n, c, turn = 0.0062, 50, 90.0, 47.5
    times = np.arange(0, 1.0 + 1e-9, 0.005)
    k = np.arange(n)[::-1]                                  # distance from the impacted end
    strain = np.zeros((len(times), n))
    for i, t in enumerate(times):
        d = c * t
        centre = d if d <= turn else 2 * turn - d           # there and back
        strain[i] = -0.05 * np.exp(-0.5 * ((k - centre) / 1.5) ** 2)
    p = first_passage(times, strain, h0)
    assert p.speed_m_s == pytest.approx(c * h0, rel=0.01)
    assert p.speed_snapshot_m_s == pytest.approx(c * h0, rel=0.01)


def test_paper_speed_reading_rounds_the_peak_position_to_whole_prisms():
    """The paper's reading: the peak moved N whole prisms in t_ref. A pulse at 41.3 prisms/s is
    20.65 prisms from the impacted end at 0.5 s: read as 21 prisms in 0.5 s."""
    from solver.analysis.observables import first_passage
    h0 = 0.0062
    times, strain = _sech2_history(41.3, 0.054, 4.0)
    p = first_passage(times, strain, h0)
    assert p.speed_paper_m_s == pytest.approx(21 * h0 / 0.5, rel=1e-12)


def _permanent_wave(c, delta_peak, w, t, n=60, h0=0.0062):
    """Level displacements and velocities (n + 1 levels, level 0 at the clamped end) of a kink
    ``u = -D (1 - tanh((s - c t) / w)) / 2`` moving ``c`` prisms/s from the impacted end (s:
    prisms from it): the levels it has passed are moved by ``D`` towards the clamped end. Its
    shortening ``-du/ds / h0`` is a sech^2 pulse of peak ``delta_peak``."""
    D = 2 * w * h0 * delta_peak
    s = (n - np.arange(n + 1)).astype(float)
    x = (s - c * t) / w
    u = -D * 0.5 * (1 - np.tanh(x))
    v = -D * 0.5 * (c / w) / np.cosh(x) ** 2
    h = h0 + u[1:] - u[:-1]
    return (h - h0) / h, v, D


def test_pulse_momentum_of_a_wave_of_permanent_shape():
    """A pulse of permanent shape carries m V sum(delta) = m c D (V = c h0, sum(delta) = D / h0):
    the node momentum sum(m v) of the same wave, computed from its velocities, agrees. A prism's
    shortening is the mean of the sech^2 over its length, so its peak is 2 w tanh(1 / (2 w))
    times the sech^2's and the effective width (integral over peak) is 1 / tanh(1 / (2 w))."""
    from solver.analysis.observables import Pulse, pulse_momentum
    h0, c, w, m, v0 = 0.0062, 40.0, 3.0, 0.0249, 0.1
    eps, v, D = _permanent_wave(c, 1e-3, w, t=0.5075, h0=h0)
    p = Pulse(*(np.nan,) * 5, 0, 0.5, np.nan)
    p.speed_m_s = c * h0
    pulse_momentum(p, eps, m * v, m, v0, fraction=1e-4)
    assert p.momentum_nodes == pytest.approx(m * c * D, rel=1e-3)
    assert p.momentum_strain == pytest.approx(m * c * D, rel=1e-3)
    assert p.momentum_ratio == pytest.approx(1.0, abs=1e-3)
    assert p.width_eff_prisms == pytest.approx(1 / np.tanh(0.5 / w), rel=2e-3)  # eps: delta 1e-3
    assert p.momentum_share == pytest.approx(c * D / v0, rel=1e-3)
    # at 10 % of the peak the range is the prisms within w acosh(sqrt(10)) of the centre
    pulse_momentum(p, eps, m * v, m, v0)
    assert p.momentum_prisms in (10, 11) and p.momentum_ratio == pytest.approx(1.0, abs=0.02)


def test_pulse_momenta_of_the_fb_column_from_strains_and_from_velocities_agree():
    """The plain FB column at 0.1 m/s, frames 0.3-0.7 s of the first passage: the leading
    pulse's momentum from its strains (m V sum(delta), V the tracked speed) and from its nodes'
    velocities agree within 6 %. Before the pulse reaches the clamped end the column's momentum
    is the impact's, m v0 (one unit mass on the impacted level; the projection on the bars is
    internal), checked on the run's summary at t_ref."""
    from solver.analysis import observables as ob
    from solver.simulate.runner import simulate
    m, v0 = 0.0249, 0.1
    kept = {}

    def setup(stack, scene, sim):
        masses = ob.momentum_masses(sim.network)

        def on_frame(frame):
            if round(frame.t, 6) in (0.3, 0.4, 0.5, 0.6, 0.7):
                kept[round(frame.t, 6)] = ob.level_momenta(sim._full_state().v,
                                                           sim.network.levels, masses)[0]
        return on_frame, None, None
    pt = simulate(ROOT_SCENES / 'fb_column.yaml', [('loading.impact.v0', v0),
                                                    ('run.t_end', 0.75)], setup=setup)
    rec, pulse = pt.record, pt.summary.to_json()['pulse']
    assert len(kept) == 5 and pulse['t_ref'] == pytest.approx(0.5)
    for t, p_level in kept.items():
        k = int(np.argmin(np.abs(rec.times - t)))
        p = ob.Pulse(*(np.nan,) * 5, 0, 0.5, np.nan)
        p.speed_m_s = pulse['speed_m_s']
        ob.pulse_momentum(p, rec.strain[k, 0], p_level, m, v0)
        assert p.momentum_prisms >= 3, t
        assert p.momentum_ratio == pytest.approx(1.0, abs=0.06), t
        assert 0.5 < p.momentum_share < 1.0, t
    assert pulse['momentum_ratio'] == pytest.approx(1.0, abs=0.06)
    assert pulse['momentum_column'] == pytest.approx(m * v0, rel=0.01)
    assert pulse['momentum_share'] == pytest.approx(pulse['momentum_nodes'] / (m * v0))


def test_front_figures_of_a_known_pulse():
    """Two stations (prisms 5 and 20 of 50 from the impacted end) registering the front at 3 %
    strain: a Gaussian of height A and width sigma reaches a level L sigma sqrt(2 ln(A / L))
    prisms ahead of its centre, at every station alike, so the time of flight is 15 prisms over
    the speed, and the first peak after the arrival is the Gaussian's height."""
    h0, speed, amp, sigma = 0.0062, 40.0, 0.054, 1.2
    times, strain = _travelling_pulse(speed, amp, sigma)
    p = track_pulse(times, strain, h0)
    assert p.front_speed_m_s == pytest.approx(speed * h0, rel=1e-3)
    assert p.front_amplitude == pytest.approx(amp, rel=1e-3)
    lead = sigma * np.sqrt(2 * np.log(amp / 0.03))
    assert p.front_arrival_s == pytest.approx((20 - lead) / speed, abs=1e-3)
    # a weaker, faster pulse ahead (below the level) is not the front
    pre_t, pre = _travelling_pulse(3 * speed, 0.02, sigma, tail=False)
    q = track_pulse(times, strain + pre, h0)
    assert q.front_speed_m_s == pytest.approx(speed * h0, rel=2e-3)
    assert q.front_amplitude == pytest.approx(amp, rel=2e-3)


def test_front_figures_are_nan_without_a_passage():
    h0 = 0.0062
    times, strain = _travelling_pulse(40.0, 0.054, sigma=1.2, t_end=0.5, tail=False)
    # the centre reaches prism 20 at 0.5 s, the history's last frame: the front has arrived,
    # its peak has not
    p = track_pulse(times, strain, h0)
    assert p.front_speed_m_s == pytest.approx(40.0 * h0, rel=1e-3)
    assert np.isnan(p.front_amplitude)
    still = track_pulse(times, np.zeros_like(strain), h0)
    assert np.isnan(still.front_speed_m_s) and np.isnan(still.front_amplitude)
    assert np.isnan(still.front_arrival_s)
    weak = track_pulse(times, 0.5 * strain, h0)          # 2.7 %: below the level everywhere
    assert np.isnan(weak.front_speed_m_s) and np.isnan(weak.front_arrival_s)
    short = track_pulse(times, strain[:, -3:], h0)       # three prisms: no two stations
    assert np.isnan(short.front_speed_m_s)


@pytest.mark.parametrize('n, near, far', [(30, 3, 12), (20, 2, 8), (80, 8, 32)])
def test_front_stations_scale_with_the_column(n, near, far):
    """On a column of ``n`` prisms the stations are a tenth and two fifths of it from the
    impacted end (written out here): the same Gaussian gives the speed over their distance, its
    height, and the arrival at the far station ``lead`` prisms ahead of the centre."""
    h0, speed, amp, sigma = 0.0062, 40.0, 0.054, 1.2
    times, strain = _travelling_pulse(speed, amp, sigma, n=n, tail=False)
    p = track_pulse(times, strain, h0)
    assert p.front_speed_m_s == pytest.approx(speed * h0, rel=1e-3)
    assert p.front_amplitude == pytest.approx(amp, rel=1e-3)
    lead = sigma * np.sqrt(2 * np.log(amp / 0.03))
    assert p.front_arrival_s == pytest.approx((far - lead) / speed, abs=1e-3)
    # a pulse that stops between the stations (it fades to nothing past prism near + 2) gives
    # an arrival at the near station only: no speed
    fade = strain * (np.arange(n)[::-1] <= near + 2)[None, :]
    assert np.isnan(track_pulse(times, fade, h0).front_speed_m_s)


def test_the_peaks_of_all_frames_at_once_equal_leading_peak_frame_by_frame():
    """``_peaks`` (every frame at once) against :func:`leading_peak` called frame by frame (the
    obvious twin), bit for bit: travelling pulses with tails, random profiles with plateaus and
    ties, peaks at either end, frames at rest, under the noise floor, with NaN."""
    from solver.analysis.observables import _peaks
    rng = np.random.default_rng(7)
    _, pulse = _travelling_pulse(60.0, 0.01, 2.0)
    noisy = rng.normal(0.0, 1e-3, (300, 40))
    plateaus = -np.round(rng.uniform(0, 3, (300, 12))) * 1e-3      # ties everywhere
    ends = np.zeros((4, 10))
    ends[0, 0], ends[1, -1], ends[2, :] = -1e-3, -1e-3, -1e-3
    ends[3, 5] = -1e-9                                               # under the floor
    nan = pulse[:5].copy()
    nan[2, 7] = np.nan
    for profiles in (pulse, noisy, plateaus, ends, nan, np.zeros((3, 8)), np.zeros((0, 8))):
        want = [leading_peak(e) for e in profiles]
        pos, amp = _peaks(profiles)
        assert np.array_equal(pos, np.array([w[0] for w in want]).reshape(-1), equal_nan=True)
        assert np.array_equal(amp, np.abs(np.array([w[1] for w in want])).reshape(-1),
                              equal_nan=True)
