"""
Where the needle tip truly is against where the physical-mode executor believes it, in the
insertion: a diagnostic that reads the simulator's truth (the executor never does).

Per throw (robots at the ``dvrk`` preset, a chosen set of effects, one registration variant as in
``bench_arm_realism.py``): the score, the tip's distance belief-to-truth when the insertion
starts, its mean and largest over the insertion, and the tip's drift (its error at the end less
its error at the start, a vector) -- what a relative motion from the insertion's start would
still carry.

Run: ``.venv/bin/python bench/probe_insertion_tip.py [--seeds 1,2] [--row
calibration+transmission+servo | all | static] [--corrections bands,bands-cables]``; a
correction's suffix ``-truewrist`` adds the hidden wrist offsets to the registered correction
(what a perfect wrist fit would give).
"""

import argparse
import logging
import os

from bench_arm_realism import LEVELS, _robot  # noqa: I100 (the bench folder's own helpers)
from bench_physical import _skill
import numpy as np
from sim_bridge.common.geometry import transform_from_pose
from sim_bridge.realism.calibration import load_arm_realism
from suture_lfd.skill.arm_registration import ROLL_BAND, register_arms
from suture_lfd.skill.executor import ExecutorConfig, execute_throw

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seeds', default='1,2')
    parser.add_argument('--pairs', default='synth1,synth2,synth3,synth4')
    parser.add_argument('--row', default='calibration+transmission+servo')
    parser.add_argument('--corrections', default='bands,bands-cables')
    args = parser.parse_args()
    logging.basicConfig(level=logging.ERROR)
    skill = _skill('synthetic', 'synth1', True)
    levels = None if args.row in ('all', 'static') else {
        k: float(any(k.startswith(p) for p in args.row.split('+'))) for k in LEVELS}
    # 'static': the static-offset robots of --error-level (offsets-only registration)
    robot = ({'static_level': 1.0} if args.row == 'static'
             else {'realism': load_arm_realism('dvrk', levels=levels)})
    print('| correction | robot | pair | score | tip at start, mm | mean, mm | max, mm | '
          'drift (x, y, z), mm | true tip off the plan, mm | believed tip off the plan, mm | '
          'failure |')
    print('|---|---|---|---|---|---|---|---|---|---|---|')
    for correction in args.corrections.split(','):
        for seed in (int(s) for s in args.seeds.split(',')):
            sim = _robot(seed, **robot)
            # 'truth': the ground-truth executor on the same robot (its reference path)
            kept = (register_arms(sim, dead_bands=args.row != 'static')
                    if correction != 'truth' else None)
            if kept is None:
                pass
            elif '-stretch' in correction or '-cables' in correction:
                kept.with_cable_model(roll_band=0.0 if '-stretch' in correction
                                      else ROLL_BAND)
            elif '-roll' in correction:
                kept.with_cable_model(stretch=np.zeros(6))
            if kept is not None and '-truewrist' in correction:
                # diagnostic: the hidden wrist offsets (roll, wrist pitch and yaw) put into the
                # registered correction
                for arm, fit in list(kept.arms.items()):
                    kept.set_arm(fit.with_wrist_offset(sim._errors[arm].joint_offset[3:6]))
            tip_local = np.append(sim.needle_geometry.point_at(1.0), 1.0)
            for pair in args.pairs.split(','):
                truth = []

                def probe(truth=truth, sim=sim, tip_local=tip_local):
                    truth.append((sim.time, sim.needle_pose() @ tip_local))

                out = execute_throw(sim, skill, pair, seed=0, physical=correction != 'truth',
                                    config=ExecutorConfig(
                                        script=sim.config.scene.expert,
                                        fit_wrist=correction.startswith('bands-wrist'),
                                    track_tool=correction.endswith('-track')),
                                    observer=probe)
                if 'ii' not in out.executed:
                    print(f'| {correction} | {seed} | {pair} | {out.score:.2f} | - | - | - | - |')
                    continue
                t_rel, poses = out.executed['ii']
                start = truth[0][0] + out.subtask_times['ii'][0]
                times = np.array([t for t, _ in truth])
                errs = []
                for t, pose in zip(t_rel, poses):
                    k = int(np.argmin(np.abs(times - (start + t))))
                    believed = transform_from_pose(pose) @ tip_local
                    errs.append(1e3 * (believed[:3] - truth[k][1][:3]))
                errs = np.array(errs)
                d = np.linalg.norm(errs, axis=1)
                drift = errs[-1] - errs[0]
                # the planned tip (the insertion's rollout), and how far the true tip and the
                # believed one pass from it (largest distance to its nearest planned point)
                _, P, Q = out.rollouts['ii']
                plan = (transform_from_pose(np.hstack([P, Q])) @ tip_local)[:, :3]
                believed = (transform_from_pose(poses) @ tip_local)[:, :3]
                true_tips = believed - 1e-3 * errs

                def off(tips, plan=plan):
                    return 1e3 * max(np.linalg.norm(plan - x, axis=1).min() for x in tips)

                print(f'| {correction} | {seed} | {pair} | {out.score:.2f} | {d[0]:.2f} | '
                      f'{d.mean():.2f} | {d.max():.2f} | '
                      f'{", ".join(f"{v:.2f}" for v in drift)} | {off(true_tips):.2f} | '
                      f'{off(believed):.2f} | {(out.failure or "-").split(";")[0]} |',
                      flush=True)
            sim.close()


if __name__ == '__main__':
    main()
