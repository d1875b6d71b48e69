"""
Command line of suture_lfd: study, sweep, info, assess, bag, view, urdf.

``sweep SWEEP.yaml`` runs a grid of studies as one job set (:mod:`suture_lfd.study.sweep`).

``info`` starts the simulator in-process (no ROS) and reports what it sees: arms, needle,
phantoms and their entry/exit marker pairs. ``bag info PATH`` summarises a recorded bag;
``bag recover PATH [--out OUT]`` rebuilds a valid bag from one whose recording was interrupted.
``view BAG`` and ``view STUDY --throw ROW`` replay a recording in the browser viewer.
``assess BAG`` scores one demonstration (skill assessment) and writes its table.
``urdf --arm PSM1`` writes an arm's URDF, the model the simulator publishes as
``/<ARM>/robot_description``, for RViz and other URDF tools.
"""

import argparse
from collections.abc import Sequence
import logging
import sys

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common.vocabulary import ARMS
from suture_lfd.study.options import add_study_arguments, add_sweep_arguments


def _fmt(v: ArrayLike) -> str:
    return '(' + ', '.join(f'{x * 1000:7.2f}' for x in np.asarray(v, float)) + ') mm'


def cmd_info(args: argparse.Namespace) -> int:
    """Start the simulator in-process and report the scene."""
    from sim_bridge.simulation import Simulation

    for phantom in ('synthetic', 'scanned'):
        sim = Simulation(phantom=phantom, rng=np.random.default_rng(args.seed))
        sim.run(args.seconds)
        print(f'phantom {phantom}: t = {sim.time:.3f} s simulated')
        for name, arm in sim.arms.items():
            state = arm.operating_state
            tip = sim.tool_pose(name)[:3, 3]
            print(f'  {name:5s} {state.state:9s} homed={state.is_homed!s:5s} tip {_fmt(tip)}')
        print(f'  needle centre {_fmt(sim.needle_pose()[:3, 3])}')
        for name, pair in sim.phantom.markers.items():
            gap = np.linalg.norm(np.asarray(pair.exit) - np.asarray(pair.entry)) * 1000
            print(f'  pair {name}: entry {_fmt(pair.entry)} exit {_fmt(pair.exit)} '
                  f'gap {gap:.1f} mm')
    return 0


def cmd_study(args: argparse.Namespace) -> int:
    """Run the study of the seed paper and write its report."""
    from suture_lfd.study import run

    return run.main(args)


def cmd_sweep(args: argparse.Namespace) -> int:
    """Run a grid of studies (seeds x methods x DMP hyper-parameters) and its report."""
    from suture_lfd.study import sweep

    return sweep.main(args)


def cmd_bag_info(args: argparse.Namespace) -> int:
    """Print the topics, types, message counts and duration of a bag."""
    from suture_lfd import bags

    try:
        summary = bags.bag_summary(args.path)
    except bags.BagError as exc:
        print(f'suture-lfd bag info: error: {exc}', file=sys.stderr)
        return 1
    print(bags.format_summary(summary))
    return 0


def cmd_bag_recover(args: argparse.Namespace) -> int:
    """Rebuild a valid bag from an unfinished or truncated one."""
    from suture_lfd import bags

    try:
        summary = bags.recover_bag(args.path, args.out)
    except bags.BagError as exc:
        print(f'suture-lfd bag recover: error: {exc}', file=sys.stderr)
        return 1
    print(bags.format_summary(summary))
    return 0


def cmd_assess(args: argparse.Namespace) -> int:
    """Score a demonstration bag and write its table of scores."""
    from pathlib import Path

    from suture_lfd import bags
    from suture_lfd.assessment.demo_scores import assess_bag, write_score_table

    bag = Path(args.bag)
    try:
        row = assess_bag(bag, segments=args.segments, pair=args.pair)
    except (bags.BagError, ValueError, OSError) as exc:
        print(f'suture-lfd assess: error: {exc}', file=sys.stderr)
        return 1
    out = Path(args.out) if args.out else bag.with_name(bag.name + '.assessment.csv')
    write_score_table(out, row)
    width = max(len(k) for k in row)
    for key, value in row.items():
        text = f'{value:.4g}' if isinstance(value, float) else str(value)
        print(f'{key:{width}s}  {text}')
    print(f'scores: {out}')
    return 0


def cmd_view(args: argparse.Namespace) -> int:
    """Open a bag or a study's throw in the viewer's page and serve it until Ctrl-C."""
    from suture_lfd.viewer.show import serve_recording

    try:
        return serve_recording(args.path, throw=args.throw, segments=args.segments,
                               host=args.host, port=args.port, speed=args.speed,
                               play=args.play, seconds=args.seconds)
    except (ValueError, OSError, KeyError) as exc:
        print(f'suture-lfd view: error: {exc}', file=sys.stderr)
        return 1


def cmd_urdf(args: argparse.Namespace) -> int:
    """Write the URDF of one arm (or of every arm into a folder) as the simulator builds it."""
    from pathlib import Path

    from sim_bridge.robot_model import simulation_urdfs

    models = simulation_urdfs(parent=args.parent)
    if args.arm == 'all':
        if not args.out:
            print('suture-lfd urdf: error: --arm all needs --out FOLDER', file=sys.stderr)
            return 2
        folder = Path(args.out)
        folder.mkdir(parents=True, exist_ok=True)
        for arm, text in models.items():
            (folder / f'{arm}.urdf').write_text(text)
            print(folder / f'{arm}.urdf')
    elif args.out:
        Path(args.out).write_text(models[args.arm])
    else:
        sys.stdout.write(models[args.arm])
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='suture-lfd', description=__doc__.split('\n\n')[0])
    sub = parser.add_subparsers(dest='command', required=True)
    info = sub.add_parser('info', help='start the simulator in-process and report the scene')
    info.add_argument('--seed', type=int, default=0)
    info.add_argument('--seconds', type=float, default=0.5, help='simulated seconds to run')
    info.set_defaults(func=cmd_info)
    study = sub.add_parser('study', help="reproduce the seed paper's evaluation",
                           description="Run the seed paper's user study and evaluation in "
                           "simulation and write its report (tables beside the paper's, "
                           'figures, CSV); rerun the same command to resume an interrupted '
                           'study.')
    add_study_arguments(study)
    study.set_defaults(func=cmd_study)
    sweep = sub.add_parser('sweep', help='run a grid of studies (seeds, methods, DMP '
                                         'hyper-parameters) as one job set',
                           description='Run the studies of a sweep file as one job set on the '
                                       'chosen engine and write a sweep report.')

    add_sweep_arguments(sweep)
    sweep.set_defaults(func=cmd_sweep)
    assess = sub.add_parser(
        'assess', help='score a demonstration bag (skill assessment)',
        description='Score one demonstration from its bag (and segment file): task and '
        'subtask times, path length, economy, smoothness and idle time of each instrument, '
        'entry/exit accuracy, needle tilt and arc deviation in the tissue, grasps; writes '
        'the table as CSV.')
    assess.add_argument('bag', help='demonstration bag directory (holding metadata.yaml)')
    assess.add_argument('--segments', default=None,
                        help='its segment file (default: segment the bag here)')
    assess.add_argument('--pair', default=None, help='pair name when the bag does not say it')
    assess.add_argument('--out', default=None,
                        help='CSV table to write (default: BAG.assessment.csv beside the bag)')
    assess.set_defaults(func=cmd_assess)
    bag = sub.add_parser('bag', help='inspect and recover rosbag2 bags (demonstrations)')
    bag_sub = bag.add_subparsers(dest='bag_command', required=True)
    bag_info = bag_sub.add_parser('info', help='topics, types, counts and duration of a bag')
    bag_info.add_argument('path', help='bag directory (holding metadata.yaml)')
    bag_info.set_defaults(func=cmd_bag_info)
    recover = bag_sub.add_parser(
        'recover', help='rebuild a valid bag from an unfinished one (recorder killed, file '
        'truncated), keeping every message of its complete chunks')
    recover.add_argument('path', help='bag directory or .mcap file to recover')
    recover.add_argument('--out', default=None,
                         help='new bag directory (default: PATH-recovered next to PATH)')
    recover.set_defaults(func=cmd_bag_recover)
    view = sub.add_parser(
        'view', help='replay a bag, or a throw of a study, in the browser viewer',
        description='Serve a recorded bag (time slider with the subtasks of its segment file, '
        'play/pause, speed) or a throw of a study (--throw ROW) in the viewer page; open the '
        'URL it prints. Ctrl-C stops it.')
    view.add_argument('path', help='bag directory, or a study folder with --throw')
    view.add_argument('--throw', default=None, metavar='ROW',
                      help="row of the study's throws.csv (1 = first throw) or a throw key")
    view.add_argument('--segments', default=None,
                      help='segment file to mark on the slider (default: <bag>.segments.npz '
                           "or the study's segments/<bag>.npz when present)")
    view.add_argument('--host', default='127.0.0.1',
                      help='interface to listen on (default 127.0.0.1: this machine only)')
    view.add_argument('--port', type=int, default=8080, help='TCP port (default 8080)')
    view.add_argument('--speed', type=float, default=1.0, help='replay speed (default 1)')
    view.add_argument('--play', action='store_true', help='start playing at once')
    view.add_argument('--seconds', type=float, default=None,
                      help='stop serving after this many seconds (default: until Ctrl-C)')
    view.set_defaults(func=cmd_view)
    urdf = sub.add_parser(
        'urdf', help="write an arm's URDF (robot model for RViz)",
        description="Write an arm's URDF, made from config/kinematics.yaml and the instrument "
        'shapes of config/world.yaml as the simulator builds the arm: the model it publishes '
        'on /<ARM>/robot_description. Joint names are those of measured_js and '
        'jaw/measured_js; the root link is the RCM frame <ARM>_base.')
    urdf.add_argument('--arm', required=True, choices=[*ARMS, 'all'],
                      help='arm to write (all: PSM1.urdf, PSM2.urdf, ECM.urdf into --out)')
    urdf.add_argument('--out', default=None,
                      help='file to write (a folder with --arm all; default: standard output)')
    urdf.add_argument('--parent', default=None, choices=['world'],
                      help='attach <ARM>_base to world where config/world.yaml places it '
                           '(default: <ARM>_base is the root)')
    urdf.set_defaults(func=cmd_urdf)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format='%(levelname)s %(name)s: %(message)s')
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == '__main__':
    sys.exit(main())
