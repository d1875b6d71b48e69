"""
Physical mode in-process: generality against the kinematic-error level, with and without the
executor's correction, beside ground-truth mode; and CPU per throw.

Ours: :func:`suture_lfd.skill.executor.execute_throw` with ``physical=True`` (markers and needle
from the rendered stereo pair, the arms' own reports; ``correction=True``: each PSM registered
against the endoscope once per simulation, the throw run on the corrected kinematics;
``correction=False``: open loop on the arms' own kinematics) on scenes with hidden dVRK
kinematic errors of level 0, 1, 3, 5 (mm class), a few error seeds each.

Anchor measured in the same run: ground-truth mode (the simulation's truth, perfect
kinematics), the same skills on the same pairs. Skills: ``pair_frame`` learnt from a scripted
demonstration on the phantom's first pair. Printed: mean score per level and mode, its ratio to
ground-truth mode, and CPU seconds per throw (the registration, once per simulation, apart).

``--study-step``: every simulation (the demonstration, both modes) at the study's physics step
(10 ms) and its thread and collision periods (:class:`suture_lfd.study.jobs.JobSettings`) instead
of ``world.yaml``'s (2 ms): the needle then rests differently, as in a study.

Run: ``.venv/bin/python bench/bench_physical.py [--phantom synthetic] [--levels 0,1,3,5]
[--seeds 1,2] [--pairs synth1,synth2] [--corrections on,off] [--study-step]``
"""

import argparse
from dataclasses import replace
import logging
import os
import time

import numpy as np
from sim_bridge.simulation import Simulation, load_simulation_config
from suture_lfd.demos.scripted_demo import record_scripted_demonstration
from suture_lfd.demos.segment_file import make_segment_file
from suture_lfd.segmentation import segment_demonstration
from suture_lfd.skill import learn_skill, training_data
from suture_lfd.skill.arm_registration import register_arms
from suture_lfd.skill.executor import execute_throw
from suture_lfd.study.jobs import JobSettings

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')


def _config(study_step, **errors):
    """The simulation's configuration: world.yaml's, or at the study's step and periods."""
    config = replace(load_simulation_config(), **errors)
    if study_step:
        s = JobSettings(out='')
        config = replace(config, world=replace(config.world, physics_step=s.physics_step),
                         loop=replace(config.loop, thread_period=s.thread_period,
                                      collision_period=max(s.collision_period,
                                                           s.physics_step)))
    return config


def _skill(phantom, first, study_step):
    sim = Simulation(_config(study_step), phantom=phantom)
    try:
        demo, _, score = record_scripted_demonstration(sim, first)
    finally:
        sim.close()
    if score.score != 1.0:
        raise SystemExit(f'the scripted demonstration on {first} failed ({score.failure})')
    return learn_skill(training_data(make_segment_file(demo, segment_demonstration(demo))),
                       'pair_frame')


def _throws(sim, skill, pairs, **kwargs):
    scores, cpu = [], []
    for pair in pairs:
        start = time.process_time()
        out = execute_throw(sim, skill, pair, seed=0, **kwargs)
        cpu.append(time.process_time() - start)
        scores.append(out.score)
        print(f'    {pair}: {out.score:.1f} {out.failure}', flush=True)
    return scores, cpu


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--phantom', default='synthetic', choices=('synthetic', 'scanned'))
    parser.add_argument('--levels', default='0,1,3,5')
    parser.add_argument('--seeds', default='1,2', help='kinematic-error seeds per level')
    parser.add_argument('--pairs', default=None, help="pairs (default: the phantom's four)")
    parser.add_argument('--corrections', default='on,off',
                        help='the executor correcting on what it sees (on), open loop (off)')
    parser.add_argument('--study-step', action='store_true',
                        help="the study's 10 ms physics step instead of world.yaml's 2 ms")
    args = parser.parse_args()
    logging.basicConfig(level=logging.ERROR)
    prefix = 'synth' if args.phantom == 'synthetic' else 'scan'
    pairs = args.pairs.split(',') if args.pairs else [f'{prefix}{k}' for k in range(1, 5)]
    levels = [float(x) for x in args.levels.split(',')]
    seeds = [int(x) for x in args.seeds.split(',')]
    corrections = [{'on': True, 'off': False}[x] for x in args.corrections.split(',')]
    skill = _skill(args.phantom, f'{prefix}1', args.study_step)

    sim = Simulation(_config(args.study_step), phantom=args.phantom)
    print('ground-truth mode (anchor)', flush=True)
    truth, truth_cpu = _throws(sim, skill, pairs)
    sim.close()
    anchor = float(np.mean(truth))
    rows = []
    for level in levels:
        for correction in corrections:
            scores, cpu, reg = [], [], []
            for seed in seeds:
                config = _config(args.study_step, kinematic_error_level=level,
                                 kinematic_error_seed=seed)
                sim = Simulation(config, phantom=args.phantom)
                if correction:
                    start = time.process_time()
                    register_arms(sim)
                    reg.append(time.process_time() - start)
                print(f'level {level:g} seed {seed} correction {correction}', flush=True)
                s, c = _throws(sim, skill, pairs, physical=True, correction=correction)
                scores += s
                cpu += c
                sim.close()
            rows.append((level, correction, float(np.mean(scores)), float(np.mean(cpu)),
                         float(np.mean(reg)) if reg else 0.0, len(scores)))

    step = JobSettings(out='').physics_step if args.study_step else load_simulation_config(
    ).world.physics_step
    print(f'\n{args.phantom}: pairs {",".join(pairs)}, error seeds {args.seeds}, physics step '
          f'{1e3 * step:g} ms')
    print(f'ground-truth mode: mean score {anchor:.3f} ({len(truth)} throws), '
          f'CPU {np.mean(truth_cpu):.2f} s per throw')
    print('| level | correction | mean score | ratio to ground truth | CPU s/throw | ratio | '
          'registration CPU s (once per robot) | throws |')
    print('|---|---|---|---|---|---|---|---|')
    for level, correction, score, cpu, reg, n in rows:
        ratio = score / anchor if anchor > 0 else float('nan')
        print(f'| {level:g} | {"on" if correction else "off"} | {score:.3f} | {ratio:.2f} | '
              f'{cpu:.2f} | {cpu / np.mean(truth_cpu):.2f} | {reg:.2f} | {n} |')


if __name__ == '__main__':
    main()
