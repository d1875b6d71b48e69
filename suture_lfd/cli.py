"""
Command line of suture_lfd: ``suture-lfd study`` (the main job), ``sweep``, ``info`` and ``bag``.

``sweep SWEEP.yaml`` runs a grid of studies as one job set (:mod:`suture_lfd.study.sweep`).

``info`` starts the simulator in-process (no ROS) and reports what it sees: arms, needle,
phantoms and their entry/exit marker pairs. ``bag info PATH`` summarises a recorded bag;
``bag recover PATH [--out OUT]`` rebuilds a valid bag from one whose recording was interrupted.
"""

import argparse
import logging
import sys

import numpy as np


def _fmt(v):
    return '(' + ', '.join(f'{x * 1000:7.2f}' for x in np.asarray(v, float)) + ') mm'


def cmd_info(args):
    """Start the simulator in-process and report the scene."""
    from sim_bridge.simulation import Simulation

    for phantom in ('synthetic', 'scanned'):
        sim = Simulation(phantom=phantom, rng=np.random.default_rng(args.seed))
        sim.run(args.seconds)
        print(f'phantom {phantom}: t = {sim.time:.3f} s simulated')
        for name, arm in sim.arms.items():
            state = arm.operating_state
            tip = (sim.T_world_base(name) @ arm.measured_cp)[:3, 3]
            print(f'  {name:5s} {state.state:9s} homed={state.is_homed!s:5s} tip {_fmt(tip)}')
        print(f'  needle centre {_fmt(sim.needle_pose()[:3, 3])}')
        for name, pair in sim.phantom.markers.items():
            gap = np.linalg.norm(np.asarray(pair.exit) - np.asarray(pair.entry)) * 1000
            print(f'  pair {name}: entry {_fmt(pair.entry)} exit {_fmt(pair.exit)} '
                  f'gap {gap:.1f} mm')
    return 0


def cmd_study(args):
    """Run the study of the seed paper and write its report."""
    try:
        from suture_lfd import study
    except ImportError:
        logging.getLogger('suture_lfd').warning(
            'the study runner is not available in this version; reporting the scene instead')
        return cmd_info(args)
    return study.main(args)


def cmd_sweep(args):
    """Run a grid of studies (seeds x methods x DMP hyper-parameters) and its report."""
    from suture_lfd.study import sweep

    return sweep.main(args)


def cmd_bag_info(args):
    """Print the topics, types, message counts and duration of a bag."""
    from suture_lfd import bags

    try:
        summary = bags.bag_summary(args.path)
    except bags.BagError as exc:
        print(f'suture-lfd bag info: error: {exc}', file=sys.stderr)
        return 1
    print(bags.format_summary(summary))
    return 0


def cmd_bag_recover(args):
    """Rebuild a valid bag from an unfinished or truncated one."""
    from suture_lfd import bags

    try:
        summary = bags.recover_bag(args.path, args.out)
    except bags.BagError as exc:
        print(f'suture-lfd bag recover: error: {exc}', file=sys.stderr)
        return 1
    print(bags.format_summary(summary))
    return 0


def build_parser():
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
    from suture_lfd.study import add_arguments as add_study_arguments

    add_study_arguments(study)
    study.set_defaults(func=cmd_study, seconds=0.5)
    sweep = sub.add_parser('sweep', help='run a grid of studies (seeds, methods, DMP '
                                         'hyper-parameters) as one job set',
                           description='Run the studies of a sweep file as one job set on the '
                                       'chosen engine and write a sweep report.')
    from suture_lfd.study.sweep import add_arguments as add_sweep_arguments

    add_sweep_arguments(sweep)
    sweep.set_defaults(func=cmd_sweep)
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
    return parser


def main(argv=None):
    logging.basicConfig(level=logging.INFO, format='%(levelname)s %(name)s: %(message)s')
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == '__main__':
    sys.exit(main())
