"""Impact waves in tensegrity columns: run, sweep, fit, lens, node, demo, replay, paper, bench.

The command line of docs/interfaces.md section 2.

User errors (bad scene, bad option, diverged simulation) print one line on stderr and exit 2 (1 for
a diverged run), never a traceback.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

from tensegrity_ros.commands.inputs import check_out, check_params_files, demo_values
from tensegrity_ros.commands.run import cmd_run
from tensegrity_ros.io.progress import progress_bar


class UserError(Exception):
    """An error the user caused; printed as one line."""


class OneLineParser(argparse.ArgumentParser):
    """argparse's parser with the project's error form: one line on stderr, ``tensegrity:`` first
    and the ``--help`` to read, exit code 2 (argparse prints its usage block above the message)."""

    def error(self, message):
        self.exit(2, f'tensegrity: {message} (see: {self.prog} --help)\n')


def cmd_bench(args):
    """``tensegrity bench ARGS``: ``python -m bench ARGS`` from the source checkout (the benchmarks
    are not part of the installed package)."""
    root = Path(__file__).resolve().parents[1]
    if not (root / 'bench' / '__main__.py').exists():
        raise UserError('bench: the benchmarks live in the source checkout (bench/); run '
                        '`python -m bench` there')
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(root)] + [p for p in os.environ.get('PYTHONPATH', '').split(os.pathsep) if p]))
    return subprocess.call([sys.executable, '-m', 'bench', *args.args], env=env)


def cmd_replay(args):
    """``tensegrity replay RUN.mcap``: republish a log over ROS 2, or convert it to Rerun."""
    from tensegrity_ros.io.mcap_reader import LogError, McapLog
    from tensegrity_ros.io.convert import to_rerun
    from tensegrity_ros.node.replay import ReplayError, replay_main
    try:
        McapLog(args.log)
        if args.to_rerun:
            status = {}
            n = to_rerun(args.log, args.to_rerun, status=status)
            print(f'{args.log}: {n} messages -> {args.to_rerun}'
                  + (' (file cut short: read up to its last complete chunk)'
                     if status.get('truncated') else ''))
            return 0
        ros_args = ['--ros-args', *args.ros_args] if args.ros_args else None
        n, truncated = replay_main(args.log, rate=args.rate, loop=args.loop, delay_s=args.delay,
                                   args=ros_args, wait_s=args.wait)
        print(f'{args.log}: replayed {n} messages'
              + (' (file cut short: read up to its last complete chunk)' if truncated else ''),
              file=sys.stderr)
    except (LogError, ReplayError) as exc:
        raise UserError(str(exc)) from None
    return 0


def cmd_paper(args):
    """``tensegrity paper``: the paper's table under every modelling variant
    (solver.studies.paper)."""
    from solver import paper
    from tensegrity_ros.io.share import find_data, searched
    fb = find_data('config/scenes/fb_column.yaml')     # a checkout's or an install's scenes
    if fb is None:
        raise UserError(f'paper: config/scenes/fb_column.yaml not found (looked in {searched()})')
    scenes = fb.parent
    models = ('sym3d',) if args.no_chain or args.set else ('sym3d', 'chain1d')
    sets = list(args.set or [])
    if sets:                 # checked on the FB scene before anything runs
        from solver import Scene
        Scene.load(fb).with_overrides(sets)
    v0s = paper.V0S[:1] if args.quick else paper.V0S
    update, close = progress_bar(paper.n_runs(v0s, models, scenes), 'paper', unit='frame',
                                 leave=False)
    try:
        result = paper.paper_table(v0s=v0s, t_end=0.6 if args.quick else 1.2, models=models,
                                   progress=update, quick=args.quick, sets=sets, scenes=scenes)
    finally:
        close()
    if args.json:
        print(json.dumps(paper.as_json(result)))
    else:
        print(paper.format_table(result, markdown=args.markdown))
    return 0


def cmd_lens(args):
    """``tensegrity lens SCENE --focus X,Z --medium-speed C``: the focusing design and its
    check (solver.studies.lens), the field in the medium (solver.analysis.field)."""
    from solver import Scene
    from solver import lens
    from tensegrity_ros.studies import lens_report
    if not (args.medium_speed > 0 and args.medium_speed < float('inf')):
        raise UserError(f'--medium-speed: must be a positive number of m/s, got '
                        f'{args.medium_speed!r}')
    focus = lens.parse_focus(args.focus)
    scene = Scene.load(args.scene)
    v0 = scene.loading.impact.v0 if args.v0 is None else args.v0
    if not (-10.0 <= v0 <= 10.0) or v0 == 0:
        raise UserError(f'--v0: {v0!r} m/s must be nonzero and within [-10, 10]')
    recorder = None
    if args.rerun:
        recorder = lens_report.recorder(scene, args.rerun)
    try:
        result = lens_report.result(scene, focus, args.medium_speed, v0, args.dims, recorder)
    finally:
        if recorder is not None:
            recorder.close()
    if recorder is not None:
        result['rerun'] = str(args.rerun)
    out_dir = Path(args.out) if args.out else Path('runs') / f'{scene.name}_lens'
    if args.plot:
        from tensegrity_ros.studies.plots import lens_field
        out_dir.mkdir(parents=True, exist_ok=True)
        result['plot'] = str(lens_field(result, out_dir / 'lens_field.png'))
    result.pop('_field')
    if args.json:
        from solver import json_safe
        print(json.dumps(json_safe(result), allow_nan=False))
    else:
        for line in lens_report.format_lines(result):
            print(line)
    return 0


def cmd_node(args):
    """``tensegrity node [--ros-args ...]``: the ROS 2 node, as ``tensegrity_node``."""
    check_params_files(args.ros_args)
    from rclpy._rclpy_pybind11 import RCLError   # rclpy exports it nowhere else
    from tensegrity_ros.node.node import main as node_main
    ros_args = ['--ros-args', *args.ros_args] if args.ros_args else []
    try:
        return node_main(['tensegrity_node', *ros_args])
    except RCLError as exc:           # rcl refused the arguments (a parameter file's layout)
        raise UserError('node: ' + str(exc).split(', at /')[0].replace('\n', ' ')) from None


def cmd_demo(args):
    """``tensegrity demo``: the node in a second process, an impact over the topic, a summary;
    with ``--focus X,Z`` a focus of the lens array instead (the plan, the arrivals the node
    measures, the focal gain). A fresh install (or an edited solver) first compiles the kernels
    on every core, saying so, so that the node starts at once and keeps its real-time pace."""
    domain = args.domain_id if args.domain_id is not None else (
        int(os.environ['ROS_DOMAIN_ID']) if os.environ.get('ROS_DOMAIN_ID') else None)
    if args.focus is None:
        v0, prestrain = demo_values(args)
    from solver import compile_all
    try:                                # every kernel on every core first (once per solver)
        compile_all()
    except RuntimeError as exc:
        raise UserError(f'demo: {exc}') from None
    if args.focus is not None:
        return _demo_focus(args, domain)
    from tensegrity_ros.node.demo import format_summary, run_demo
    out = args.out or 'runs/demo'
    return _demo_report(lambda: run_demo(
        args.scene or DEMO_SCENE, v0=v0, duration_s=args.duration, rtf=args.rtf, out_dir=out,
        domain_id=domain, record=not args.no_record, prestrain=prestrain), format_summary, out)


def _demo_report(run, format_lines, out):
    """Run a demo on this machine only (DDS discovery on localhost), print its summary; exit
    code 0 when the node exited cleanly."""
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    try:
        summary = run()
    except RuntimeError as exc:
        raise UserError(f'demo: {exc}') from None
    for line in format_lines(summary):
        print(line)
    print(f'  summary: {out}/summary.json')
    return 0 if summary['node_exit_code'] == 0 else 1


DEMO_SCENE = 'config/scenes/fb_column.yaml'
FOCUS_SCENE = 'config/scenes/lens_focus.yaml'


def _demo_focus(args, domain):
    from solver import lens

    from tensegrity_ros.node.demo import format_focus_summary, run_focus_demo
    focus = lens.parse_focus(args.focus)
    if not focus[1] > 0:
        raise UserError(f'--focus: the depth Z must be > 0, got {focus[1]:g}')
    if not (0 < args.medium_speed < float('inf')):
        raise UserError(f'--medium-speed: must be a positive number of m/s, got '
                        f'{args.medium_speed!r}')
    out = args.out or 'runs/demo_focus'
    return _demo_report(lambda: run_focus_demo(
        focus, args.scene or FOCUS_SCENE, speed=args.medium_speed, rtf=args.rtf, out_dir=out,
        domain_id=domain, record=not args.no_record), format_focus_summary, out)


def cmd_sweep(args):
    """``tensegrity sweep``: one run per point of a grid, on Dask
    (tensegrity_ros.studies.sweep)."""
    from tensegrity_ros.studies import sweep
    try:
        return sweep.main(args)
    except sweep.SweepError as exc:
        raise UserError(str(exc)) from None


def cmd_fit(args):
    """``tensegrity fit``: scene values that reproduce target figures
    (tensegrity_ros.studies.fit)."""
    from tensegrity_ros.studies import fit
    from tensegrity_ros.studies.grid import SweepError
    try:
        return fit.main(args)
    except SweepError as exc:
        raise UserError(str(exc)) from None


def _convergence_figures(p):
    p.add_argument('--convergence-figures', metavar='F1,F2',
                   help='the pulse figures the convergence check judges (default: all), e.g. '
                        'front_speed_m_s,front_amplitude; implies --convergence')


def _study_options(p, seed_help):
    """The options sweeps and fits share: run length, Dask workers or scheduler, the local
    cluster's dashboard, seed."""
    p.add_argument('--t-end', type=float, help='simulated time of every run, s')
    p.add_argument('--workers', type=int,
                   help='N > 1: a local Dask cluster of N worker processes; 1: in this process '
                        'on one thread (default: in this process, one thread per core)')
    p.add_argument('--scheduler', metavar='ADDRESS',
                   help='an existing Dask scheduler, e.g. tcp://HOST:8786')
    p.add_argument('--dashboard-address', metavar='HOST:PORT',
                   help='where the local cluster\'s Dask dashboard listens (default 127.0.0.1 '
                        'on a free port, this machine only; 0.0.0.0:8787 = every interface)')
    p.add_argument('--no-dashboard', action='store_true',
                   help='start the local cluster without its dashboard')
    p.add_argument('--seed', type=int, default=0, help=seed_help + ' (default 0)')


def _scene_command(sub, name, func, help, scene_help='scene YAML file'):
    """A sub-command that reads a scene file: its parser, with the scene argument."""
    p = sub.add_parser(name, help=help)
    p.add_argument('scene', help=scene_help)
    p.set_defaults(func=func)
    return p


def build_parser():
    parser = OneLineParser(prog='tensegrity', description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest='command', required=True)
    p = _scene_command(sub, 'run', cmd_run, 'run a scene headless and summarise the strain wave',
                       'scene YAML file (config/scenes/*.yaml)')
    p.add_argument('--set', action='append', metavar='KEY=VALUE',
                   help='override a scene value, e.g. integrator.dt=2e-4 (repeatable)')
    p.add_argument('--v0', type=float, help='impact velocity, m/s (positive = compressive)')
    p.add_argument('--prestrain', type=float, help='cross-cable prestrain p')
    p.add_argument('--t-end', type=float, help='simulated time, s')
    p.add_argument('--out', help='output directory (summary.json, plots)')
    p.add_argument('--plot', action='store_true', help='write a PNG of the strain wave')
    p.add_argument('--mcap', action='store_true',
                   help='record the run to the rosbag2 bag folder OUT/run/ (run_0.mcap, '
                        'metadata.yaml; the node\'s topics)')
    p.add_argument('--rerun', action='store_true',
                   help='record the run to OUT/run.rrd (Rerun; open it with: rerun OUT/run.rrd)')
    p.add_argument('--rerun-connect', nargs='?', metavar='URL',
                   const='rerun+http://127.0.0.1:9876/proxy',
                   help='stream the run to a running Rerun viewer (default URL %(const)s)')
    p.add_argument('--json', action='store_true', help='print the summary as one JSON object')
    p.add_argument('--convergence', nargs='?', type=float, const=0.01, metavar='TOL',
                   help='also run the point with every step control refined (dt/2, contact '
                        'resolution x2) and exit 1 unless every pulse figure moves by at most '
                        'TOL (relative; default %(const)s)')
    _convergence_figures(p)
    p = _scene_command(sub, 'sweep', cmd_sweep, 'one run per point of a grid of scene values, '
                       'on Dask; a Parquet and CSV table')
    p.add_argument('--grid', action='append', metavar='KEY=V1,V2|KEY=START:STOP:N',
                   help='a swept scene key (as --set names it): listed values, N values from '
                        'START to STOP, or START:STOP with --samples (repeatable)')
    p.add_argument('--samples', type=int, metavar='N',
                   help='N Latin-hypercube points over the START:STOP ranges')
    p.add_argument('--out', help='output directory (default runs/sweeps/SCENE)')
    _study_options(p, 'seed of --samples')
    p.add_argument('--plot', metavar='FIGURE',
                   help='heat map of FIGURE (e.g. pulse.amplitude) over the first two keys')
    p.add_argument('--convergence', nargs='?', type=float, const=0.01, metavar='TOL',
                   help='also run every point with every step control refined (dt/2, contact '
                        'resolution x2) and add the check to its row: column converged, '
                        'False where a pulse figure moves by more than TOL (relative; default '
                        '%(const)s)')
    _convergence_figures(p)
    p = _scene_command(sub, 'fit', cmd_fit, 'scene values that reproduce target figures '
                       '(differential evolution on Dask)')
    p.add_argument('--target', required=True, metavar='TARGET.yaml',
                   help='cases: [{set: {...}, figures: {...}, weights: {...}}, ...]')
    p.add_argument('--free', action='append', metavar='KEY=LO:HI',
                   help='a continuous scene key and its bounds (repeatable)')
    p.add_argument('--choice', action='append', metavar='KEY=A,B',
                   help='a discrete scene key and its values (repeatable)')
    _study_options(p, 'seed of the optimiser')
    p.add_argument('--popsize', type=int, default=8,
                   help='population per free dimension (default 8)')
    p.add_argument('--maxiter', type=int, default=20, help='generations at most (default 20)')
    p.add_argument('--convergence', nargs='?', type=float, const=0.01, metavar='TOL',
                   help='run the best point\'s cases again with every step control refined '
                        '(dt/2, contact resolution x2) and exit 1 unless every fitted figure '
                        'moves by at most TOL (relative; default %(const)s)')
    p.add_argument('--no-polish', action='store_true',
                   help='skip the least-squares refinement of the best point')
    p.add_argument('--json', action='store_true', help='print the result as one JSON object')
    p.add_argument('--write-scene', metavar='OUT.yaml',
                   help='write the scene with the best values')
    p = sub.add_parser('replay', help='republish an MCAP log over ROS 2 (with /clock), or '
                       'convert it to a Rerun recording')
    p.add_argument('log', metavar='RUN', help='MCAP log: a bag folder or an .mcap file '
                   '(tensegrity run --mcap, the node\'s record_mcap)')
    p.add_argument('--rate', type=float, default=1.0, help='playback speed factor (default 1)')
    p.add_argument('--loop', action='store_true', help='play again from the start when done')
    p.add_argument('--delay', type=float, default=0.5,
                   help='seconds to wait for subscribers before playing (default 0.5)')
    p.add_argument('--wait', type=float, default=0.0, metavar='S',
                   help='first wait up to S s until a subscriber matches (then --delay)')
    p.add_argument('--to-rerun', metavar='OUT.rrd', help='write a Rerun recording instead')
    p.add_argument('--ros-args', nargs=argparse.REMAINDER, help='ROS arguments (remapping)')
    p.set_defaults(func=cmd_replay)
    p = sub.add_parser('bench', add_help=False,
                       help='benchmarks: work-precision chart, stability map, peer comparison, '
                            'adapter costs (python -m bench; --help lists its options)')
    p.add_argument('args', nargs=argparse.REMAINDER, help='options of python -m bench')
    p.set_defaults(func=cmd_bench)
    p = sub.add_parser('paper', help="the paper's table (FB and RB, v0 = 0.1, 0.125, 0.15) "
                       'under every modelling variant, next to the paper\'s FB values')
    p.add_argument('--json', action='store_true', help='print one JSON object')
    p.add_argument('--markdown', action='store_true', help='print the table as Markdown')
    p.add_argument('--quick', action='store_true', help='v0 = 0.1 only, 0.6 s (smoke run)')
    p.add_argument('--no-chain', action='store_true', help='skip the chain1d rows')
    p.add_argument('--set', action='append', metavar='KEY=VALUE',
                   help='a modelling option for every variant, e.g. structure.mass_placement='
                        'unit_bases, materials.bar_mass_fraction=0.3, loading.impact.mode='
                        'striker, contact.lock=penalty (repeatable; skips the chain1d rows)')
    p.set_defaults(func=cmd_paper)
    p = _scene_command(sub, 'lens', cmd_lens, 'focus the pulses of an array into a host '
                       'medium: one prestrain per column on the delay law of a focus, checked by '
                       'simulation', 'scene YAML of an array (config/scenes/lens_focus.yaml)')
    p.add_argument('--focus', required=True, metavar='X,Z',
                   help='focus in the medium, m (x along the array, depth z > 0)')
    p.add_argument('--medium-speed', type=float, required=True, metavar='C',
                   help='wave speed of the host medium, m/s')
    p.add_argument('--v0', type=float, help='impact velocity, m/s (default: the scene\'s)')
    p.add_argument('--dims', type=int, choices=(2, 3), default=2,
                   help='geometric spreading of the field: 2 (line sources) or 3 (points)')
    p.add_argument('--plot', action='store_true', help='write OUT/lens_field.png')
    p.add_argument('--rerun', metavar='OUT.rrd',
                   help='record the check run and the field over sim_time to a Rerun file')
    p.add_argument('--out', help='output directory (default runs/<scene>_lens)')
    p.add_argument('--json', action='store_true', help='print one JSON object')
    p = sub.add_parser('node', help='the ROS 2 node tensegrity_sim (as tensegrity_node)')
    p.add_argument('--ros-args', dest='ros_args', nargs=argparse.REMAINDER,
                   help='ROS arguments: --ros-args -p NAME:=VALUE --params-file config/node.yaml')
    p.set_defaults(func=cmd_node)
    p = sub.add_parser('demo', help='start the node, command an impact over ROS 2, summarise')
    p.add_argument('--scene', help='scene YAML (default config/scenes/fb_column.yaml; with '
                   '--focus config/scenes/lens_focus.yaml)')
    p.add_argument('--v0', default='0.1', help='impact velocity m/s, or one per column: 0.1,0.12')
    p.add_argument('--focus', metavar='X,Z',
                   help='focus the lens array at X,Z m (x along the array, depth z > 0) with '
                        '~/cmd/focus instead of an impact: prints the plan, the arrivals the '
                        'node measures and the focal gain')
    p.add_argument('--medium-speed', type=float, default=1.0, metavar='C',
                   help='wave speed of the host medium for --focus, m/s (default 1.0)')
    p.add_argument('--prestrain', help='prestrain before the impact, or one per column')
    p.add_argument('--duration', type=float, default=1.2,
                   help='simulated seconds collected after the impact (default 1.2)')
    p.add_argument('--rtf', type=float, default=1.0,
                   help='real-time factor (0 = fast as possible)')
    p.add_argument('--out', help='output directory (default runs/demo, with --focus '
                   'runs/demo_focus)')
    p.add_argument('--domain-id', type=int,
                   help='ROS_DOMAIN_ID (default: env, else 100 + pid %% 50)')
    p.add_argument('--no-record', action='store_true', help='no MCAP / Rerun recording')
    p.set_defaults(func=cmd_demo)
    p = sub.add_parser('compile', help='compile the solver kernels into their cache now, on '
                       'every core (otherwise the first run compiles what it uses)')
    p.add_argument('--processes', type=int, help='parallel compiler processes (default: cores)')
    p.set_defaults(func=cmd_compile)
    return parser


def cmd_compile(args):
    from solver import compile_all
    if args.processes is not None and args.processes < 1:
        raise UserError(f'--processes: must be at least 1, got {args.processes}')
    try:
        spent = compile_all(args.processes)
    except RuntimeError as exc:
        raise UserError(str(exc)) from None
    if not spent:
        print('the solver kernels are already compiled')
    return 0


def _installed_data(args):
    """A scene or target named as in the docs (``config/scenes/fb_column.yaml``) that the working
    directory does not hold is taken from the package's data: the checkout, a colcon or a pip
    install (:func:`tensegrity_ros.io.share.find_data`); anything else is left as given."""
    from tensegrity_ros.io.share import find_data
    for name in ('scene', 'target'):
        value = getattr(args, name, None)
        if isinstance(value, str) and value and not os.path.exists(value):
            found = find_data(value)
            if found is not None:
                setattr(args, name, str(found))


def main(argv=None):
    from solver import NetworkError
    from solver import SceneError
    from solver import SimulationDiverged

    parser = build_parser()
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ['bench']:          # its options are python -m bench's own
        args = argparse.Namespace(func=cmd_bench, args=argv[1:])
    else:
        args = parser.parse_args(argv)
    _installed_data(args)
    try:
        if getattr(args, 'out', None):
            check_out(args.out)
        return args.func(args)
    except SimulationDiverged as exc:
        print(f'tensegrity: {exc}', file=sys.stderr)
        return 1
    except (SceneError, NetworkError, UserError, ValueError) as exc:
        print(f'tensegrity: {exc}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print('tensegrity: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
