"""
Simulator speed: simulated seconds per wall second of whole expert throws, IK rate, stereo render.

Ours: :class:`sim_bridge.simulation.Simulation` (PSM1, PSM2, ECM, needle, thread, phantom; no
rendering) at its default physics step, driven by the scripted expert at 100 Hz through all five
subtasks of a throw.

Anchor measured in the same run: a SurRoL-style PyBullet scene -- three dynamic arm multibodies
(the PSM/ECM modified-DH chains, as SurRoL's re-topologised serial URDFs) driven by
``setJointMotorControlArray(POSITION_CONTROL)`` every step, a needle body and a pad, stepped
with ``stepSimulation`` at 1/240 s. Stated anchors (sim_anchors.md): SurRoL's PyBullet scene
runs at about 18-20x real time at 1/240 s steps; the AMBF Surgical Robotics Challenge at 1x.
Target (issue): >= 100x real time at the default step.

Run: ``.venv/bin/python bench/bench_sim.py``; ``--before REF`` (a commit, branch or tag) also
measures the same throws with the code of REF (a temporary git worktree, run in a subprocess with
its packages first on ``PYTHONPATH``), alternating with today's code for ``--rounds`` rounds, and
prints the CPU time per throw before and after side by side (the best round of each: the machine
may be shared, CPU time is what other processes disturb least).
"""

import argparse
import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time

import numpy as np
from sim_bridge.bullet import bullet_client, pybullet
from sim_bridge.common.geometry import quaternion_from_matrix
from sim_bridge.kinematics import ecm_kinematics, psm_kinematics
from sim_bridge.simulation import Simulation, load_simulation_config
from suture_lfd.planning.episode import run_episode, start_episode
from suture_lfd.planning.expert import ScriptedExpert

ANCHOR_SURROL_REALTIME = (18.0, 20.0)
ANCHOR_AMBF_REALTIME = 1.0
TARGET_REALTIME = 100.0
TARGET_RATIO = 0.3  # ours / SurRoL-style scene, full throws at the default step (per CPU second)


def expert_throws(config, pairs, control_period):
    """Run one whole expert throw per pair; return (simulated s, wall s, CPU s, scores)."""
    sim_s = wall_s = cpu_s = 0.0
    scores = []
    sims = {}
    for name in pairs:
        phantom = 'scanned' if name.startswith('scan') else 'synthetic'
        if phantom not in sims:
            sims[phantom] = Simulation(config, phantom=phantom)
        sim = sims[phantom]
        start_episode(sim, name, seed=0)
        if phantom == 'scanned':
            sim.attach_needle('PSM2')  # the needle start does not stay on the scanned pad
        expert = ScriptedExpert(sim.target_pair, sim.needle_geometry, sim.config.scene.expert,
                                kinematics=sim.kinematics['PSM2'])
        start, cpu = time.perf_counter(), time.process_time()
        sim_s += run_episode(sim, expert, control_period, chunk=control_period, settle=0.0,
                             reset=False)
        wall_s += time.perf_counter() - start
        cpu_s += time.process_time() - cpu
        scores.append(sim.score().score)
        sim.pop_events()
    for sim in sims.values():
        sim.close()
    return sim_s, wall_s, cpu_s, scores


REPO = Path(__file__).resolve().parents[1]


def throws_in_subprocess(tree, pairs, control_period):
    """Run :func:`expert_throws` with the packages of source tree ``tree``; return its results."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(tree)] + [p for p in os.environ.get('PYTHONPATH', '').split(os.pathsep) if p]))
    out = subprocess.run(
        [sys.executable, __file__, '--throws-json', '--control-period', str(control_period),
         '--pairs', *pairs], env=env, check=True, capture_output=True, text=True).stdout
    result = json.loads(out.strip().splitlines()[-1])
    if Path(result['source']).resolve() != (Path(tree) / 'sim_bridge').resolve():
        raise RuntimeError(f'the throws ran the code in {result["source"]}, not {tree}')
    return result


def compare_before_after(ref, pairs, control_period, rounds):
    """
    Time the throws with the code of ``ref`` and with this tree, alternating, ``rounds`` times.

    Returns
    -------
    dict
        ``'before'`` and ``'after'``: lists of per-round results (simulated s, wall s, CPU s,
        scores), and ``'ref'``: the commit measured as before.

    """
    commit = subprocess.run(['git', '-C', str(REPO), 'rev-parse', '--verify', f'{ref}^{{commit}}'],
                            check=True, capture_output=True, text=True).stdout.strip()
    scratch = tempfile.mkdtemp(prefix='bench-sim-before-')
    tree = Path(scratch) / 'tree'
    subprocess.run(['git', '-C', str(REPO), 'worktree', 'add', '--detach', str(tree), commit],
                   check=True, capture_output=True)
    runs = {'before': [], 'after': [], 'ref': commit}
    try:
        for k in range(rounds):
            order = (('before', tree), ('after', REPO))
            for label, source in order if k % 2 == 0 else order[::-1]:
                runs[label].append(throws_in_subprocess(source, pairs, control_period))
    finally:
        subprocess.run(['git', '-C', str(REPO), 'worktree', 'remove', '--force', str(tree)],
                       check=False, capture_output=True)
        os.rmdir(scratch)
    return runs


def chain_body(client, chain, base_position):
    """A dynamic PyBullet multibody of a modified-DH chain (0.1 kg links, capsule shapes)."""
    frames = list(chain.joint_placements()) + [chain.tooltip_offset]
    types = [pybullet.JOINT_REVOLUTE if r else pybullet.JOINT_PRISMATIC
             for r in chain.is_revolute] + [pybullet.JOINT_FIXED]
    n = len(frames)
    shape = client.createCollisionShape(pybullet.GEOM_CAPSULE, radius=0.004, height=0.02)
    return client.createMultiBody(
        baseMass=0.0, basePosition=base_position,
        linkMasses=[0.1] * n,
        linkCollisionShapeIndices=[shape] * n,
        linkVisualShapeIndices=[-1] * n,
        linkPositions=[F[:3, 3].tolist() for F in frames],
        linkOrientations=[quaternion_from_matrix(F[:3, :3]).tolist() for F in frames],
        linkInertialFramePositions=[[0.0, 0.0, 0.0]] * n,
        linkInertialFrameOrientations=[[0.0, 0.0, 0.0, 1.0]] * n,
        linkParentIndices=list(range(n)),
        linkJointTypes=types,
        linkJointAxis=[[0.0, 0.0, 1.0]] * n), chain.n_joints


def surrol_style_scene(seconds, rng):
    """Step a SurRoL-like scene for ``seconds``; return simulated s per wall s and per CPU s."""
    client = bullet_client.BulletClient(connection_mode=pybullet.DIRECT)
    client.setGravity(0.0, 0.0, -9.81)
    dt = 1.0 / 240.0
    client.setTimeStep(dt)
    pad = client.createCollisionShape(pybullet.GEOM_BOX, halfExtents=[0.05, 0.05, 0.005])
    client.createMultiBody(baseMass=0.0, baseCollisionShapeIndex=pad)
    needle = client.createCollisionShape(pybullet.GEOM_CAPSULE, radius=0.0005, height=0.02)
    client.createMultiBody(baseMass=0.01, baseCollisionShapeIndex=needle,
                           basePosition=[0.0, 0.0, 0.02])
    psm, ecm = psm_kinematics(), ecm_kinematics()
    arms = [chain_body(client, psm, [-0.12, 0.0, 0.3]), chain_body(client, psm, [0.12, 0.0, 0.3]),
            chain_body(client, ecm, [0.0, -0.12, 0.4])]
    chains = [psm, psm, ecm]
    steps = int(round(seconds / dt))
    start, cpu = time.perf_counter(), time.process_time()
    for k in range(steps):
        for (body, n), chain in zip(arms, chains):
            if k % 24 == 0:  # a new joint goal 10 times a second, as an RL action would give
                goal = rng.uniform(0.5 * chain.lower, 0.5 * chain.upper)
                goal[2] = 0.12
                client.setJointMotorControlArray(body, list(range(n)), pybullet.POSITION_CONTROL,
                                                 targetPositions=goal.tolist())
        client.stepSimulation()
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    client.disconnect()
    return seconds / wall, seconds / cpu


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--pairs', nargs='+', default=['synth1', 'synth3'])
    parser.add_argument('--control-period', type=float, default=0.01)
    parser.add_argument('--anchor-seconds', type=float, default=10.0)
    parser.add_argument('--renders', type=int, default=5)
    parser.add_argument('--before', metavar='REF',
                        help='also measure the throws with the code of this git commit/branch')
    parser.add_argument('--rounds', type=int, default=3,
                        help='alternating before/after rounds with --before (best one counts)')
    parser.add_argument('--throws-json', action='store_true', help=argparse.SUPPRESS)
    args = parser.parse_args()
    config = load_simulation_config()
    if args.throws_json:  # one measurement for --before, in the subprocess
        sim_s, wall_s, cpu_s, scores = expert_throws(config, args.pairs, args.control_period)
        import sim_bridge
        print(json.dumps({'sim_s': sim_s, 'wall_s': wall_s, 'cpu_s': cpu_s, 'scores': scores,
                          'source': str(Path(sim_bridge.__file__).parent)}))
        return
    runs = None
    if args.before:
        runs = compare_before_after(args.before, args.pairs, args.control_period, args.rounds)
        best = min(runs['after'], key=lambda r: r['cpu_s'])
        sim_s, wall_s, cpu_s, scores = best['sim_s'], best['wall_s'], best['cpu_s'], best['scores']
    else:
        sim_s, wall_s, cpu_s, scores = expert_throws(config, args.pairs, args.control_period)
    sim = Simulation(config)
    ours, ours_cpu = sim_s / wall_s, sim_s / cpu_s
    anchor, anchor_cpu = surrol_style_scene(args.anchor_seconds, np.random.default_rng(0))

    chain = sim.kinematics['PSM2']
    rng = np.random.default_rng(1)
    Q = rng.uniform(chain.lower, chain.upper, size=(2000, chain.n_joints))
    T = chain.fk_batch(Q)
    start = time.perf_counter()
    for k in range(200):
        chain.ik(T[k], q_ref=Q[k])
    ik_scalar = 200 / (time.perf_counter() - start)
    start = time.perf_counter()
    chain.ik_batch(T, q_ref=Q)
    ik_batch = len(T) / (time.perf_counter() - start)

    sim.render()
    times = []
    for _ in range(args.renders):
        start = time.perf_counter()
        sim.render()
        times.append(time.perf_counter() - start)
    render_s = float(np.median(times))
    sim.close()

    cam = config.camera
    print(f'physics step {config.world.physics_step * 1e3:.1f} ms, expert at '
          f'{1.0 / args.control_period:.0f} Hz, pairs {", ".join(args.pairs)} (scores {scores})')
    print(f'ours: {sim_s:.1f} simulated s in {wall_s:.1f} wall s = {ours:.2f}x real time')
    print(f'SurRoL-style PyBullet scene measured in this run (1/240 s steps, 3 dynamic arms): '
          f'{anchor:.1f}x real time')
    print(f'stated anchors: SurRoL {ANCHOR_SURROL_REALTIME[0]:.0f}-'
          f'{ANCHOR_SURROL_REALTIME[1]:.0f}x, AMBF challenge {ANCHOR_AMBF_REALTIME:.0f}x')
    print(f'ratios: ours / SurRoL-style measured {ours / anchor:.3f}; ours / SurRoL stated '
          f'{ours / ANCHOR_SURROL_REALTIME[0]:.3f}-{ours / ANCHOR_SURROL_REALTIME[1]:.3f}; '
          f'ours / AMBF {ours / ANCHOR_AMBF_REALTIME:.2f}; target {TARGET_REALTIME:.0f}x: '
          f'{"met" if ours >= TARGET_REALTIME else "NOT met"} '
          f'({ours / TARGET_REALTIME:.3f} of the target)')
    print(f'per CPU second (robust on a shared machine): ours {ours_cpu:.2f}x, SurRoL-style '
          f'{anchor_cpu:.1f}x, ratio {ours_cpu / anchor_cpu:.3f}')
    if runs is not None:
        print_before_after(runs, len(args.pairs), anchor_cpu)
    print(f'IK: scalar {ik_scalar:,.0f} solves/s, batch {ik_batch:,.0f} solves/s')
    print(f'stereo render ({cam.width}x{cam.height}, RGB + depth, both eyes, CPU): '
          f'{render_s * 1e3:.0f} ms')


def print_before_after(runs, n_throws, anchor_cpu):
    """Print CPU per throw and real time per CPU second, before and after, side by side."""
    print(f'before = {runs["ref"][:12]}, after = this tree; {len(runs["after"])} alternating '
          f'rounds, best (least CPU) round of each; the machine may be shared')
    rows = {}
    for label in ('before', 'after'):
        best = min(runs[label], key=lambda r: r['cpu_s'])
        cpus = sorted(r['cpu_s'] for r in runs[label])
        rows[label] = (best['cpu_s'] / n_throws, cpus[len(cpus) // 2] / n_throws,
                       best['sim_s'] / best['cpu_s'], best['scores'])
    print(f'{"":8}{"CPU s/throw (best)":>20}{"(median)":>10}{"x real time/CPU s":>19}'
          f'{"/ SurRoL-style":>16}  scores')
    for label, (best, median, per_cpu, scores) in rows.items():
        print(f'{label:8}{best:20.3f}{median:10.3f}{per_cpu:19.2f}{per_cpu / anchor_cpu:16.3f}'
              f'  {scores}')
    print(f'after / before: CPU per throw {rows["after"][0] / rows["before"][0]:.3f} '
          f'({rows["before"][0] / rows["after"][0]:.2f}x faster); same scores: '
          f'{rows["after"][3] == rows["before"][3]}')
    ratio = rows['after'][2] / anchor_cpu
    print(f'ratio target {TARGET_RATIO} (per CPU second): {ratio:.3f}, '
          f'{"met" if ratio >= TARGET_RATIO else "NOT met"}')


if __name__ == '__main__':
    main()
