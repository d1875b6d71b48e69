"""
What storing a throw's replay costs the study: CPU time and bytes per throw.

Executes the same throw (a test segment file's skill on synth2, in-process) with and without
the :class:`suture_lfd.viewer.throw_replay.ThrowSampler`, alternately, and prints the CPU time
of each (``time.process_time``: the machine may be shared), the ratio, and the replay file's
size. Then renders the throw's filmstrip and prints its CPU time.

Run: ``.venv/bin/python bench/bench_viewer_replay.py [--repeats 2]``.
"""

import argparse
from pathlib import Path
import tempfile
import time

from sim_bridge.simulation import Simulation
from suture_lfd.skill import learn_skill
from suture_lfd.skill.executor import execute_throw
from suture_lfd.viewer.filmstrip import write_filmstrip
from suture_lfd.viewer.throw_replay import ThrowSampler, recording_from_file

SEGMENTS = Path(__file__).resolve().parent.parent / 'test' / 'suture_lfd' / 'data' / \
    'study_S01_synth1.npz'


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--repeats', type=int, default=2)
    parser.add_argument('--pair', default='synth2')
    args = parser.parse_args()
    skill = learn_skill(SEGMENTS, 'paper')
    sim = Simulation()
    plain, sampled, sizes = [], [], []
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / 'replay.npz'
        for _ in range(args.repeats):
            t0 = time.process_time()
            execute_throw(sim, skill, args.pair, seed=1)
            plain.append(time.process_time() - t0)
            t0 = time.process_time()
            sampler = ThrowSampler(sim)
            outcome = execute_throw(sim, skill, args.pair, seed=1, observer=sampler)
            sizes.append(sampler.save(path, args.pair, outcome.events, outcome.subtask_times))
            sampled.append(time.process_time() - t0)
        print(f'throw on {args.pair}: {outcome.duration:.1f} s simulated, score {outcome.score}, '
              f'{len(sampler.rows)} samples')
        print(f'CPU time without replay: {min(plain):.2f} s, with replay (sampling + saving): '
              f'{min(sampled):.2f} s, ratio {min(sampled) / min(plain):.3f}')
        print(f'replay file: {sizes[-1] / 1024:.1f} kB per throw')
        t0 = time.process_time()
        write_filmstrip(recording_from_file(path), Path(folder) / 'strip.png', sim=sim)
        print(f'filmstrip (5 ECM frames): {time.process_time() - t0:.2f} s CPU')
    sim.close()


if __name__ == '__main__':
    main()
