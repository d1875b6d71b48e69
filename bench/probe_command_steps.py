"""
Step by step through the insertion: the controller's tool target, the command the correction
sends for it, the joints that command asks for, and where the executor then believes the tool:
a diagnostic that reads the simulator's setpoints (the executor never does).

Per throw (robots at the ``dvrk`` preset or a chosen set of its effects, the registration that
fits the dead bands; ``--reports``: its backlash inverse as it was, directions from the
reported joints): the believed tool's distance from the target sent one step before (mean,
largest; mm and deg), the command's distance from the target (what the correction adds), the
joints' distance to their limits, the steps where the command allows for another play than the
reported joints' (and by how much), and the arm's setpoint against the joints the command's
inverse asks for.
With ``--dump`` the rows of every step of the insertion are printed.

Run: ``.venv/bin/python bench/probe_command_steps.py [--seeds 1] [--pairs synth1] [--row all]``
"""

import argparse
import logging
import math
import os

from bench_arm_realism import LEVELS, _robot  # noqa: I100 (the bench folder's own helpers)
from bench_physical import _skill
import numpy as np
from sim_bridge.common.geometry import invert_transform
from sim_bridge.realism.calibration import load_arm_realism
from suture_lfd.skill import arm_registration
from suture_lfd.skill.arm_registration import register_arms
from suture_lfd.skill.executor import ExecutorConfig, execute_throw
from suture_lfd.skill.hysteresis import PSM_STILL
from suture_lfd.teleop.mapping import rotation_angle

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seeds', default='1')
    parser.add_argument('--pairs', default='synth1,synth2')
    parser.add_argument('--row', default='all')
    parser.add_argument('--arm', default='PSM2')
    parser.add_argument('--subtask', default='ii')
    parser.add_argument('--dump', action='store_true')
    parser.add_argument('--reports', action='store_true',
                        help="the backlash inverse's directions from the reported joints")
    args = parser.parse_args()
    logging.basicConfig(level=logging.ERROR)
    skill = _skill('synthetic', 'synth1', True)
    levels = None if args.row == 'all' else {
        k: float(any(k.startswith(p) for p in args.row.split('+'))) for k in LEVELS}
    realism = load_arm_realism('dvrk', levels=levels)
    steps = []
    original = arm_registration.CorrectedController.step

    def step(self, obs):
        # the controller's target (where the tool should truly be), then the command
        cmd = self.controller.step(obs)
        sent = self.correction.command(cmd, obs.q or {})
        arm = args.arm
        T = (cmd.T_world_tool or {}).get(arm)
        if T is not None and obs.q is not None and arm in self.correction.arms:
            tracker = self.correction._plays.get(arm)
            fit = self.correction.arms[arm]
            q = np.asarray(obs.q[arm], dtype=float)
            local = invert_transform(fit.T_world_base) @ sent.T_world_tool[arm]
            try:
                q_to = np.asarray(fit.kinematics.ik_unchecked(local, q.tolist()))
            except ValueError:
                q_to = np.full(6, np.nan)
            inverse = self.correction._inverse.get(arm)
            if not self.correction.inverse_on_targets:
                heading = tracker.heading(q, q_to, PSM_STILL) if tracker else [0.0] * 6
            else:
                heading = inverse.play if inverse is not None and inverse.play else [0.0] * 6
            steps.append({'t': float(obs.t), 'label': cmd.subtask, 'target': np.array(T),
                          'sent': np.array(sent.T_world_tool[arm]),
                          'believed': np.array(obs.T_world_tool[arm]), 'q': q, 'q_to': q_to,
                          'play': np.array(tracker.play if tracker else [0.0] * 6),
                          'heading': np.array(heading)})
        return sent

    arm_registration.CorrectedController.step = step
    try:
        for seed in (int(s) for s in args.seeds.split(',')):
            sim = _robot(seed, realism=realism)
            register_arms(sim).inverse_on_targets = not args.reports
            kin = sim.kinematics[args.arm]
            lower, upper = np.asarray(kin.lower), np.asarray(kin.upper)
            for pair in args.pairs.split(','):
                steps.clear()
                setpoints = []

                def probe(sim=sim, setpoints=setpoints):
                    # called before the step's command is applied: the previous command's
                    setpoints.append(np.asarray(sim.arms[args.arm].setpoint_jp, dtype=float))

                out = execute_throw(sim, skill, pair, seed=0, physical=True,
                                    config=ExecutorConfig(script=sim.config.scene.expert),
                                    observer=probe)
                rows = [k for k, s in enumerate(steps) if s['label'] == args.subtask]
                if not rows:
                    print(seed, pair, out.score, 'no', args.subtask)
                    continue
                dp, da, cp, hp, lim, sp = [], [], [], [], [], []
                for k in rows[:-1]:
                    s, nxt = steps[k], steps[k + 1]
                    d = nxt['believed'][:3, 3] - s['target'][:3, 3]
                    dp.append(1e3 * np.linalg.norm(d))
                    R = s['target'][:3, :3].T @ nxt['believed'][:3, :3]
                    da.append(math.degrees(rotation_angle(R)))
                    cp.append(1e3 * np.linalg.norm(s['sent'][:3, 3] - s['target'][:3, 3]))
                    hp.append(np.abs(s['heading'] - s['play']))
                    lim.append(np.minimum(s['q_to'] - lower, upper - s['q_to']))
                    sp.append(np.abs(setpoints[k + 1] - s['q_to']))
                    if args.dump:
                        print(f"{s['t']:.2f} dp {dp[-1]:.3f} da {da[-1]:.2f} "
                              f"q {np.round(s['q'], 4)} q_to-q {np.round(s['q_to'] - s['q'], 4)} "
                              f"play {np.round(s['play'], 4)} heading-play "
                              f"{np.round(s['heading'] - s['play'], 4)} "
                              f"setpoint-q_to {np.round(setpoints[k + 1] - s['q_to'], 4)}")
                hp, lim, sp = np.array(hp), np.array(lim), np.array(sp)
                crossing = (hp > 1e-9).any(axis=1)
                print(f'robot {seed} {pair} score {out.score:.2f} ({(out.failure or "-")[:30]}) '
                      f'steps {len(dp)}: believed-target mm mean {np.mean(dp):.3f} max '
                      f'{np.max(dp):.3f}, deg mean {np.mean(da):.2f} max {np.max(da):.2f}; '
                      f'command-target mm {np.mean(cp):.2f}; command play != tracked play on '
                      f'{crossing.sum()} steps (joints {np.flatnonzero(hp.max(axis=0) > 1e-9)}, '
                      f'largest {np.round(hp.max(axis=0), 4)}); smallest margin to a limit '
                      f'{np.round(lim.min(axis=0), 4)}; setpoint vs IK of the command '
                      f'{np.round(sp.max(axis=0), 5)}', flush=True)
            sim.close()
    finally:
        arm_registration.CorrectedController.step = original


if __name__ == '__main__':
    main()
