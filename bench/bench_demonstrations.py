"""
Synthetic demonstrations over the cohort: durations, success, segmentation, and their cost.

Ours: :func:`suture_lfd.demos.demonstrator.run_demonstration` for every subject of the cohort on
the chosen pairs (default: the first pair of each phantom), then
:func:`suture_lfd.segmentation.segment_demonstration` on the record, compared with the
subtask the subject was doing (``labels``); and the demonstration bag round trip
(:func:`suture_lfd.demos.demo_bag.write_demonstration_bag`, :func:`~suture_lfd.demos.demo_bag.
demonstration_from_bag`).

Anchor measured in the same run, on the same simulation: the scripted expert's throw on the
same pair (the subject's planner without skill noise or hesitations), whose wall time per
simulated second the ratios are taken against.

Prints: per subject and pair the demonstration duration (s of simulated time), attempts, score,
entry error and trauma, whether the five subtasks were found and how far the found subtask
boundaries are from the subject's own (median, s); then group means and ratios.

Run: ``.venv/bin/python bench/bench_demonstrations.py [--pairs synth1 scan1] [--seed 0]``
"""

import argparse
from pathlib import Path
import statistics
import tempfile
import time

import numpy as np
from sim_bridge.simulation import Simulation
from suture_lfd.demos.cohort import load_cohort
from suture_lfd.demos.demo_bag import demonstration_from_bag, write_demonstration_bag
from suture_lfd.demos.demonstrator import DemonstrationError, run_demonstration
from suture_lfd.planning.episode import run_episode, start_episode
from suture_lfd.planning.expert import ScriptedExpert
from suture_lfd.segmentation import SUBTASKS, segment_demonstration

NAMES = [name for name, _, _ in SUBTASKS]


def expert_throw(sim, pair):
    target = start_episode(sim, pair, 0)
    expert = ScriptedExpert(target, sim.needle_geometry, sim.config.scene.expert,
                            kinematics=sim.kinematics['PSM2'])
    wall = time.perf_counter()
    elapsed = run_episode(sim, expert, 5 * sim.dt, timeout=60.0, chunk=5 * sim.dt, settle=0.0,
                          reset=False)
    return elapsed, time.perf_counter() - wall


def boundary_error(run, seg):
    t = run.demo.t
    errors = []
    for sub in seg.subtasks:
        labelled = t[run.labels == sub.name]
        errors.append(abs(sub.start_time - labelled[0]))
    return float(np.median(errors))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--pairs', nargs='+', default=['synth1', 'scan1'])
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--subjects', nargs='*', default=None)
    args = parser.parse_args()
    subjects = [s for s in load_cohort(seed=args.seed)
                if args.subjects is None or s.name in args.subjects]
    sims = {}
    rows = []
    anchors = {}
    for pair in args.pairs:
        phantom = 'scanned' if pair.startswith('scan') else 'synthetic'
        sim = sims.setdefault(phantom, Simulation(phantom=phantom))
        sim_s, wall = expert_throw(sim, pair)
        anchors[pair] = wall / sim_s
        print(f'anchor expert {pair}: {sim_s:.2f} s simulated in {wall:.2f} s wall '
              f'({wall / sim_s:.3f} wall s per simulated s)')
        for s in subjects:
            wall = time.perf_counter()
            try:
                run = run_demonstration(sim, s, pair, seed=args.seed)
            except DemonstrationError as exc:
                print(f'{s.name} {s.group:11s} {pair}: FAILED {exc}')
                rows.append((s, pair, None, None, False, None, None))
                continue
            wall = time.perf_counter() - wall
            try:
                seg = segment_demonstration(run.demo)
                ok, err = True, boundary_error(run, seg)
            except ValueError as exc:
                ok, err = False, None
                print(f'   segmentation failed: {exc}')
            with tempfile.TemporaryDirectory() as tmp:
                t_bag = time.perf_counter()
                write_demonstration_bag(Path(tmp) / 'bag', run.demo)
                demonstration_from_bag(Path(tmp) / 'bag')
                t_bag = time.perf_counter() - t_bag
            print(f'{s.name} {s.group:11s} {pair}: {run.demo.duration:6.2f} s, attempts '
                  f'{run.attempts}, score {run.score.score}, entry {run.score.entry_error_mm:.2f}'
                  f' mm, trauma {run.score.trauma_mm:.2f} mm, five subtasks {ok}'
                  + (f' (median boundary error {err:.3f} s)' if ok else '')
                  + f'; wall {wall:.1f} s ({wall / run.demo.duration / anchors[pair]:.2f} x '
                  f'anchor per simulated s), bag round trip {t_bag:.2f} s')
            rows.append((s, pair, run.demo.duration, run.attempts, ok, err, wall))
    for group in ('experienced', 'naive'):
        mine = [r for r in rows if r[0].group == group and r[2] is not None]
        if not mine:
            continue
        durations = [r[2] for r in mine]
        mean = statistics.mean(durations)
        print(f'{group}: {len(mine)} demonstrations, duration mean {mean:.2f} s (min '
              f'{min(durations):.2f}, max {max(durations):.2f}), segmented '
              f'{sum(r[4] for r in mine)}/{len(mine)}, attempts mean '
              f'{statistics.mean(r[3] for r in mine):.2f}')
    done = [r for r in rows if r[2] is not None]
    print(f'overall: {len(done)}/{len(rows)} demonstrations succeeded, segmentation success '
          f'{sum(r[4] for r in done)}/{len(done)}')


if __name__ == '__main__':
    main()
