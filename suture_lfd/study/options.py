"""
The command-line options of ``suture-lfd study`` and ``suture-lfd sweep``.

Every ``suture-lfd`` command builds its whole parser, so this module stays light: it imports
nothing that loads PyBullet or the jobs (the commands import :mod:`suture_lfd.study.run` and
:mod:`suture_lfd.study.sweep` only when they run).
"""

import argparse

from suture_lfd.study import held_out, physical

QUICK_SUBJECTS = 2
QUICK_PAIRS = 2


def add_study_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of ``suture-lfd study`` to an argparse parser."""
    parser.add_argument('--seed', type=int, default=0,
                        help='cohort and study seed (same seed, same report; default 0)')
    parser.add_argument('--out', default='study', help='report folder (default ./study)')
    parser.add_argument('--workers', type=int, default=None,
                        help='parallel worker processes (default: the number of CPUs; half '
                             'of them with --via-ros); with --engine dask, the local '
                             "cluster's workers")
    parser.add_argument('--engine', default='local',
                        help='where the jobs run: local (a process pool, default), dask (a '
                             'local Dask cluster), tcp://HOST:PORT or scheduler-file:PATH (an '
                             'existing Dask cluster)')
    parser.add_argument('--quick', action='store_true',
                        help=f'small study: {QUICK_SUBJECTS} subjects (one per group), '
                             f'{QUICK_PAIRS} pairs per phantom')
    parser.add_argument('--methods', default=None,
                        help='comma-separated methods (default: all registered methods)')
    parser.add_argument('--subjects', type=int, default=None,
                        help='number of subjects, taken in turn from each group')
    parser.add_argument('--pairs', type=int, default=None,
                        help='marker pairs per phantom (the first ones in suturing order)')
    parser.add_argument('--phantoms', default=None,
                        help='comma-separated phantoms (default: every phantom of the design)')
    parser.add_argument('--cohort', default=None, help='cohort file (default config/cohort.yaml)')
    parser.add_argument('--via-ros', action='store_true',
                        help='execute every throw through the ROS node graph: a simulator and '
                             'an executor node process per throw, a private ROS domain per '
                             'worker (demonstrations stay in-process; ~10x slower per throw)')
    parser.add_argument('--assessment', choices=('subject', 'cohort', 'off'),
                        default='subject',
                        help='learning with skill assessment, reported beside learning from '
                             'every demonstration: a rejected demonstration is replaced by '
                             "the subject's own best accepted one (subject, default) or the "
                             "cohort's best accepted one on that pair (cohort); off: no "
                             'assessment')
    parser.add_argument('--tissue', default='none',
                        help='needle-in-tissue realism preset of config/realism_tissue.yaml '
                             '(tissue forces, the needle turning in the jaw, a pad that gives, '
                             'thread drag): none (default) or tissue')
    parser.add_argument('--camera', default='none',
                        help='endoscope realism preset of config/realism_camera.yaml that '
                             "physical mode's perception looks through (dvrk: a distorting "
                             'lens and its rectification, 30 frames per second reaching the '
                             'robot 50 ms after the scene they show): none (default, an ideal '
                             'camera) or dvrk')
    held_out.add_arguments(parser)
    physical.add_arguments(parser)
    parser.add_argument('--plan', action='store_true',
                        help='write the configuration (subjects, seeds, jobs) and stop')
    parser.add_argument('--report-only', action='store_true',
                        help='write the report from the results stored so far, run nothing')


def add_sweep_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of ``suture-lfd sweep`` to an argparse parser."""
    parser.add_argument('sweep_file', help='sweep file (YAML, see config/sweep_table1.yaml)')
    parser.add_argument('--out', default='sweep', help='sweep folder (default ./sweep)')
    parser.add_argument('--workers', type=int, default=None,
                        help='worker processes (default: the number of CPUs)')
    parser.add_argument('--engine', default='local',
                        help='local (default), dask, tcp://HOST:PORT or scheduler-file:PATH')
    parser.add_argument('--plan', action='store_true',
                        help='write the configuration and jobs and stop')
