"""``tensegrity run``: one scene run to its end, with its optional recordings (an MCAP bag folder,
a Rerun file or viewer), a strain-wave plot and a summary (text, or strict JSON with ``--json``).
The command line itself is :mod:`tensegrity_ros.cli`."""
from __future__ import annotations

import dataclasses
import gc
import json
import math
import sys
from pathlib import Path

from tensegrity_ros.io.progress import progress_bar
from tensegrity_ros.io.sinks import FanOut, Sink


def _raise(sink, exc):
    """A recorder of ``tensegrity run`` that fails stops the run (its output would be wrong)."""
    raise exc


def _open_mcap(stack, sinks, scene, sim, path):
    """Record the run to the bag folder ``path`` (MCAP, the node's topics, ``metadata.yaml``): a
    :class:`~tensegrity_ros.io.sinks.Sink` added to ``sinks`` (the run's
    :class:`~tensegrity_ros.io.sinks.FanOut`, as the node's); closed by ``stack``, also on
    SIGTERM.
    Logs each impact as the command the node would receive and as an event (the text the Rerun
    recording shows, :func:`_impact_text`), then every output frame."""
    from solver import run_frame
    from tensegrity_ros.io.mcap_frames import FrameLog, marker_every, network_metadata
    from tensegrity_ros.io.mcap_writer import McapRecorder, signals_as_interrupt
    stack.enter_context(signals_as_interrupt())
    recorder = stack.enter_context(McapRecorder(
        path, bag=True, metadata=network_metadata(sim.network, scene.name)))
    log = FrameLog(recorder, sim.network, marker_every=marker_every(scene.run.output_dt))
    columns = scene.loading.impact.columns

    def impact(i, entry):
        v0 = entry.v0_m_s
        values = [v0] if columns is None else [v0 if c in columns else 0.0
                                               for c in range(sim.network.n_columns)]
        log.command('~/cmd/impact', values, 'all' if columns is None else 'column', run_frame(sim),
                    f'impact v0 = {v0:g} m/s (scene {scene.name})')
        log.event(entry.t_s, _impact_text(i, entry, scene, sim))
    sinks.add(Sink(frame=log.frame, impact=impact))
    return str(recorder.folder)


def _open_rerun(stack, sinks, scene, sim, path=None, url=None):
    """Record the run to a Rerun ``.rrd`` at ``path`` and/or stream it to the viewer at ``url``
    (a :class:`~tensegrity_ros.io.sinks.Sink` added to ``sinks``); closed by ``stack``. Logs
    each impact as a command event: the first starts with ``impact`` (the heat map starts
    there), the later ones of a train with ``train impact``."""
    from tensegrity_ros.io.rerun_sink import RerunRecorder
    recorder = stack.enter_context(RerunRecorder(sim.network, path, connect=url))

    def impact(i, entry):
        recorder.command(entry.t_s, _impact_text(i, entry, scene, sim))
    sinks.add(Sink(frame=recorder.frame, impact=impact))
    return str(path) if path is not None else url


def _impact_text(i, entry, scene, sim):
    """The event text of impact ``i`` of a run (``entry``: an ``ImpactApplied``):
    the first starts with ``impact`` (the Rerun heat map starts there), the later ones of a train
    with ``train impact``."""
    from solver import ImpactTrain
    n, columns = len(ImpactTrain(scene.loading.impact, sim.dt)), scene.loading.impact.columns
    where = 'all columns' if columns is None else f'columns {list(columns)}'
    text = f'v0 = {entry.v0_m_s:g} m/s on {where}'
    if i == 0:
        return f'impact {text}' + (f' (1 of {n})' if n > 1 else '')
    return f'train impact {i + 1} of {n}: {text}'


def run_overrides(args):
    """The scene overrides of ``tensegrity run``'s options, in the order they apply."""
    sets = list(args.set or [])
    if args.v0 is not None:
        sets.append(('loading.impact.v0', args.v0))
    if args.prestrain is not None:
        sets.append(('prestrain', args.prestrain))
    if args.t_end is not None:
        sets.append(('run.t_end', args.t_end))
    return sets


def _refined_run(args):
    """With ``--convergence``: the point of ``args`` with every step control refined, started on
    a thread (the kernels release the GIL: it runs beside the main run on a second core). Returns
    ``(refined overrides, future, stop)``, or None without the option; ``stop.set()`` ends the
    refined run after its current output interval (the main run failed or was interrupted:
    nothing waits for it).
    Bad input raises here, before either run starts."""
    figures = getattr(args, 'convergence_figures', None)
    if args.convergence is None and figures is None:
        return None
    import threading
    from concurrent.futures import ThreadPoolExecutor
    from solver import Scene
    from solver import convergence
    from solver import simulate_scene as simulate
    if args.convergence is None:
        args.convergence = convergence.TOLERANCE
    convergence.check_tolerance(args.convergence)
    args.convergence_figures = None if figures is None else convergence.check_figures(figures)
    overrides = run_overrides(args)
    refined = convergence.refined_overrides(Scene.load(args.scene).with_overrides(overrides))
    stop = threading.Event()

    def interval_done(n):          # run()'s progress hook: no frames recorded for it
        if stop.is_set():
            raise _Stopped()

    pool = ThreadPoolExecutor(1, thread_name_prefix='tensegrity-refined')
    future = pool.submit(simulate, args.scene, overrides + refined,
                         setup=lambda stack, scene, sim: (None, interval_done, None))
    pool.shutdown(wait=False)
    return refined, future, stop


class _Stopped(Exception):
    """The refined run of ``--convergence`` was told to stop."""


def _found(value):
    return value is not None and math.isfinite(value)


def _pulse_line(p, t_end):
    """The summary's line on the leading pulse ``p`` (a
    :class:`~solver.analysis.observables.Pulse`), or None without one. The amplitude is read at
    ``T_REF``; a run that ends before it, or whose pulse reaches the clamped end first, still
    reports the speed and median amplitude of the window."""
    from solver import T_REF
    if p is None:
        return None
    speed = f"{p.speed_m_s:.3f} m/s" if _found(p.speed_m_s) else 'n/a'
    median = f"{p.amplitude_median:.4f}" if _found(p.amplitude_median) else 'n/a'
    if _found(p.amplitude):
        return (f"  pulse: amplitude {p.amplitude:.4f} at t = {p.t_ref:g} s (median "
                f"{median}), speed {speed}, width {p.width_prisms} prisms")
    if not _found(p.speed_m_s) and not _found(p.amplitude_median):
        return f"  pulse: none found by t = {t_end:g} s"
    why = (f"it reached the clamped end at t = {p.arrival_end_s:.3g} s"
           if _found(p.arrival_end_s) and p.arrival_end_s < T_REF
           else f"the run ends at t = {t_end:g} s")
    return (f"  pulse: speed {speed}, median amplitude {median} in the window; no amplitude "
            f"at t = {T_REF:g} s: {why}")


def _front_line(p, n_prisms):
    """The summary's line on the front (``front_*`` of the leading pulse ``p``), or None where
    the front did not reach both stations (:func:`~solver.analysis.front.front_stations` of a
    column of ``n_prisms``)."""
    from solver import FRONT_LEVEL, front_stations
    stations = front_stations(n_prisms)
    if p is None or not _found(p.front_speed_m_s) or stations is None:
        return None
    near, far = stations
    peak = (f"first peak {p.front_amplitude:.4f} there" if _found(p.front_amplitude)
            else 'still rising at the end')
    return (f"  front ({100 * FRONT_LEVEL:g} % strain): {p.front_speed_m_s:.3f} m/s from prism "
            f"{near} to {far}, at prism {far} at t = {p.front_arrival_s:.3g} s, {peak}")


def _convergence(args, summary, refined_run, tolerance):
    """The check of ``--convergence`` of the run of ``summary`` (a ``RunSummary``): ``(its JSON
    object, the one line of a failure or None)``. A failed check also runs the sensitivity twin
    (:func:`_sensitivity`)."""
    from solver import convergence
    from solver import SimulationDiverged
    refined, future, _ = refined_run
    try:
        point = future.result()
    except SimulationDiverged as exc:
        return ({'tolerance': tolerance, 'refined': dict(refined), 'converged': False,
                 'refined_run': str(exc)},
                f'convergence check: the refined run ({convergence.describe(refined)}) '
                f'diverged: {exc}')
    check = convergence.compare(convergence.figures_of(summary),
                                convergence.figures_of(point.summary), tolerance,
                                args.convergence_figures)
    if check['converged'] is False:
        check['sensitivity'] = _sensitivity(args, check, refined, point)
    return (dict(convergence.jsonable(check), refined=dict(refined),
                 refined_steps_taken=point.summary.steps_taken),
            convergence.failure(check, refined))


def _sensitivity(args, check, refined, point):
    """A failed check: the refined run twice more, with every impact velocity changed by
    ``convergence.PERTURBATION`` up and down (on two threads: the kernels release the GIL; a
    progress bar for the pair), and which failing figures move by more than the tolerance under
    either (:func:`solver.simulate.convergence.sensitivity`); None when the run has no impact
    velocity to change or a twin diverges."""
    from concurrent.futures import ThreadPoolExecutor
    from solver import convergence
    from solver import frame_count, simulate_scene as simulate
    from solver import SimulationDiverged
    rel = convergence.PERTURBATION
    perturbed = [convergence.perturbed_overrides(point.scene, r) for r in (rel, -rel)]
    if perturbed[0] is None:
        return None
    run = point.scene.run
    update, close = progress_bar(2 * (frame_count(run.t_end, run.output_dt) - 1),
                                 'sensitivity twins', unit='frame', leave=False)
    base = run_overrides(args) + list(refined)
    try:
        with ThreadPoolExecutor(2, thread_name_prefix='tensegrity-twin') as pool:
            twins = [pool.submit(simulate, args.scene, base + p,
                                 setup=lambda stack, scene, sim: (None, update, None))
                     for p in perturbed]
            twin_figures = [convergence.figures_of(t.result().summary) for t in twins]
    except SimulationDiverged:
        return None
    finally:
        close()
    return convergence.sensitivity(check, convergence.figures_of(point.summary), *twin_figures)


STRAIN_NOTE = 0.5       # |strain| from which the summary says what the strain measure means


def _strain_line(strain):
    """The summary's line on the strain measure where the run's largest |strain| reaches
    :data:`STRAIN_NOTE` (a figure beyond 1 does not read as a fraction of the height), or
    None. Strain is (h - h0) / h (negative in compression): h / h0 = 1 / (1 - strain)."""
    import numpy as np
    strain = np.asarray(strain)
    if not strain.size or not np.abs(strain).max() >= STRAIN_NOTE:
        return None
    lo, hi = float(strain.min()), float(strain.max())
    parts = []
    if lo <= -STRAIN_NOTE:
        parts.append(f'the largest compression {lo:.3g} is a prism at h_min/h0 = '
                     f'{1.0 / (1.0 - lo):.3g}')
    if hi >= STRAIN_NOTE:
        parts.append(f'the largest extension {hi:+.3g} a prism at h_max/h0 = '
                     f'{1.0 / (1.0 - hi):.3g}' if hi < 1.0 else
                     f'the largest extension {hi:+.3g}')
    return ('  strain is (h - h0)/h (h: prism height, h0: at rest; negative in compression, '
            'unbounded as h -> 0): ' + ', '.join(parts))


def _changes(part):
    """``amplitude 1.2 %, speed_m_s found in one run only``: the changes of a check (or of its
    sensitivity) in the JSON's form (:func:`solver.simulate.convergence.jsonable`)."""
    return ', '.join(f'{k} found in one run only' if k in part.get('found_in_one_run', ())
                     else f'{k} {100 * c:.3g} %' for k, c in part['changes'].items()
                     if c is not None or k in part.get('found_in_one_run', ()))


def cmd_run(args):
    refined_run = _refined_run(args)
    try:
        return _run(args, refined_run)
    finally:
        if refined_run is not None:
            refined_run[2].set()


def _run(args, refined_run):
    from solver import frame_count, simulate_scene as simulate

    if args.rerun or args.rerun_connect:
        from tensegrity_ros.io import rerun_sink  # noqa: F401  (imported before gc.freeze below)
    outputs, ctx = {}, {}

    def setup(stack, scene, sim):
        t_end, output_dt = scene.run.t_end, scene.run.output_dt
        out_dir = Path(args.out) if args.out else None
        if out_dir is None and (args.plot or args.mcap or args.rerun):
            out_dir = Path('runs') / scene.name
        if out_dir is not None:
            out_dir.mkdir(parents=True, exist_ok=True)
        ctx['out_dir'] = out_dir
        update, close = progress_bar(frame_count(t_end, output_dt) - 1, scene.name,
                                     unit='frame', leave=False)
        stack.callback(close)
        sinks = FanOut(on_error=_raise)      # a recorder that fails stops the run
        if args.mcap:
            from tensegrity_ros.io import mcap_frames as mcap_run, mcap_writer as recording  # noqa: F401
        # The objects of the imports and the set-up (some 160 000) are moved out of the garbage
        # collector's reach: otherwise its first full collection, 50-80 ms holding the GIL, tends
        # to fall in the run (with a Rerun recording: in the recorder's start, measured)
        gc.freeze()
        if args.mcap:
            outputs['mcap'] = _open_mcap(stack, sinks, scene, sim, out_dir / 'run')
        if args.rerun or args.rerun_connect:
            outputs['rerun'] = _open_rerun(stack, sinks, scene, sim,
                                           out_dir / 'run.rrd' if args.rerun else None,
                                           args.rerun_connect)
        return sinks.frame, update, sinks.impact

    point = simulate(args.scene, run_overrides(args), setup=setup)
    scene, rec, out_dir = point.scene, point.record, ctx['out_dir']
    v0 = scene.loading.impact.v0
    if args.plot:
        from tensegrity_ros.studies.plots import strain_wave
        outputs['plot'] = str(strain_wave(rec, out_dir / 'strain_wave.png',
                                          title=f'{scene.name}: v0 = {v0} m/s'))
    summary = point.summary.with_outputs(**outputs)
    result = summary.to_json()
    check, problem = (None, None) if refined_run is None else _convergence(
        args, summary, refined_run, args.convergence)
    if check is not None:
        result['convergence'] = check
    if out_dir is not None:
        (out_dir / 'summary.json').write_text(json.dumps(result, indent=2, allow_nan=False))
    if args.json:
        print(json.dumps(result, allow_nan=False))
    else:
        s = summary
        rtf = s.real_time_factor if _found(s.real_time_factor) else 0.0
        print(f"{s.scene}: {s.model} + {s.integrator}, dt = {s.dt:g} s, t_end = {s.t_end:g} s, "
              f"{s.steps_taken} steps in {s.wall_time_s:.2f} s ({rtf:.1f}x real time)")
        print(f"  energy ledger: balance error {s.energy_balance_error:.2e} (largest; "
              f"limit {scene.divergence.energy_error:g}), work {s.energy_work_J:.3e} J "
              f"in {len(s.impacts)} impact(s); constraint error {s.constraint_error_rel:.2e}")
        if s.contacts_met and check is None:
            print(f"  contact: bars touched in {s.contacts_met} force evaluations; "
                  f"figures read after a contact can depend on the steps (--convergence "
                  f"checks them)")
        for line in (_pulse_line(s.pulse, s.t_end),
                     _front_line(s.pulse, point.sim.network.n_prisms), _strain_line(rec.strain)):
            if line:
                print(line)
        if check is not None and 'changes' in check:
            from solver import describe
            moved = _changes(check) or 'no pulse figures to compare'
            verdict = {True: 'converged', False: 'NOT converged', None: 'nothing to check'}
            from solver import FIGURES
            judged = ('' if len(check.get('figures') or FIGURES) == len(FIGURES)
                      else f"; judged on {', '.join(check['figures'])}")
            print(f"  convergence ({describe(check['refined'].items())}): {moved}: "
                  f"{verdict[check['converged']]} (limit {100 * check['tolerance']:g} %"
                  f"{judged})")
            sens = check.get('sensitivity')
            if sens:
                moved = _changes(sens)
                print(f"  sensitivity (impact velocities x (1 ± {sens['perturbation']:g}), "
                      f"refined steps): {moved}: "
                      f"{', '.join(sens['sensitive']) or 'none'} sensitive")
        for key, path in dataclasses.asdict(s.outputs).items():
            if path:
                print(f'  {key}: {path}')
    if problem is not None:
        print(f'tensegrity: {problem}', file=sys.stderr)
        return 1
    return 0
