"""
Executor speed: whole DMP throws per second in-process, and where the time goes.

Ours: :func:`suture_lfd.skill.executor.execute_throw` (reset, home, plan with the DMP rollouts, run
the
:class:`~suture_lfd.skill.executor.ThrowExecutor` at the control period until the hand-over is
done) with a ``paper`` skill learnt from a scripted demonstration on ``synth1``.

Anchor measured in the same run, on the same simulation: the scripted expert's whole throw
(:class:`suture_lfd.planning.expert.ScriptedExpert`, what the executor's scripted parts are built
from). The ratios say what the executor adds on top of the simulator; the breakdown (planning,
controller steps, simulator) says where a faster study has to save.

Run: ``.venv/bin/python bench/bench_executor.py [--throws N] [--control-period S]``
"""

import argparse
import time

from sim_bridge.simulation import Simulation
from suture_lfd.demos.scripted_demo import record_scripted_demonstration
from suture_lfd.demos.segment_file import make_segment_file
from suture_lfd.planning.episode import run_episode, start_episode
from suture_lfd.planning.expert import ScriptedExpert
from suture_lfd.segmentation import segment_demonstration
from suture_lfd.skill import learn_skill, training_data
from suture_lfd.skill.executor import ExecutorConfig, ThrowExecutor, execute_throw


class _Timed:
    """Accumulates the wall time spent in a method of a class while the bench runs."""

    def __init__(self, cls, name):
        self.cls, self.name, self.total, self.calls = cls, name, 0.0, 0
        self.original = getattr(cls, name)
        timed = self

        def wrapper(*args, **kwargs):
            start = time.perf_counter()
            try:
                return timed.original(*args, **kwargs)
            finally:
                timed.total += time.perf_counter() - start
                timed.calls += 1

        setattr(cls, name, wrapper)

    def restore(self):
        setattr(self.cls, self.name, self.original)


def expert_throw(sim, pair, control_period):
    """One scripted expert throw; return (wall s, simulated s, score)."""
    target = start_episode(sim, pair, 0)
    start = time.perf_counter()
    expert = ScriptedExpert(target, sim.needle_geometry, sim.config.scene.expert,
                            kinematics=sim.kinematics['PSM2'])
    t0 = sim.time
    run_episode(sim, expert, control_period, always_settle=True)
    return time.perf_counter() - start, sim.time - t0, sim.score().score


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--throws', type=int, default=4, help='executor throws to time')
    parser.add_argument('--control-period', type=float, default=0.01)
    args = parser.parse_args()
    pairs = ['synth2', 'synth3', 'synth4', 'synth1']

    sim = Simulation()
    demo, _, score = record_scripted_demonstration(sim, 'synth1')
    if score.score != 1.0:
        raise SystemExit(f'the scripted demonstration failed ({score.failure})')
    data = training_data(make_segment_file(demo, segment_demonstration(demo)))
    start = time.perf_counter()
    skill = learn_skill(data, 'paper')
    learn_s = time.perf_counter() - start

    anchor_wall, anchor_sim, anchor_score = expert_throw(sim, 'synth2', args.control_period)

    results = {}
    for label, config in (('executor', ExecutorConfig(script=sim.config.scene.expert)),
                          ('executor, every target re-sent',
                           ExecutorConfig(script=sim.config.scene.expert,
                                          resend_unchanged=True))):
        timers = [_Timed(ThrowExecutor, 'plan'), _Timed(ThrowExecutor, 'step'),
                  _Timed(Simulation, 'step'), _Timed(Simulation, 'apply')]
        wall = sim_s = 0.0
        scores = []
        n = args.throws if label == 'executor' else 1
        for k in range(n):
            start = time.perf_counter()
            outcome = execute_throw(sim, skill, pairs[k % len(pairs)], seed=k, config=config,
                                    control_period=args.control_period)
            wall += time.perf_counter() - start
            sim_s += sim.time  # execute_throw starts every throw from a reset scene
            scores.append(outcome.score)
        for timer in timers:
            timer.restore()
        results[label] = (n, wall, sim_s, scores,
                          {f'{t.cls.__name__}.{t.name}': t.total for t in timers})

    print(f'skill learning (ii + iv, LWR): {learn_s * 1e3:.1f} ms')
    print(f'anchor: scripted expert throw on synth2: {anchor_wall:.2f} s wall for '
          f'{anchor_sim:.2f} s simulated ({anchor_sim / anchor_wall:.2f}x real time), '
          f'score {anchor_score}')
    for label, (n, wall, sim_s, scores, parts) in results.items():
        per = wall / n
        print(f'{label}: {n} throws, {n / wall:.3f} throws/s, {per:.2f} s per throw '
              f'({per / anchor_wall:.2f}x the expert throw), {sim_s / wall:.2f}x real time, '
              f'scores {scores}')
        print('    share of the wall time: '
              f'planning {parts["ThrowExecutor.plan"] / wall:.1%}, '
              f'controller steps {parts["ThrowExecutor.step"] / wall:.1%}, '
              f'Simulation.apply (servo_cp IK) {parts["Simulation.apply"] / wall:.1%}, '
              f'Simulation.step {parts["Simulation.step"] / wall:.1%}')


if __name__ == '__main__':
    main()
