"""
Closed-form PSM IK and FK throughput, side by side with PyBullet's iterative IK.

Anchor: SurRoL drives its PSM with PyBullet's ``calculateInverseKinematics``, measured at about
1 ms per call with a median 1.6 mm tip error (PyBullet 3.2.7, SurRoL's PSM URDF). Here the same
PyBullet call runs on the same modified-DH chain, built as a PyBullet multibody, started near
each target as in tracking, in the same process as the closed-form solver.

Run: ``.venv/bin/python bench/bench_ik.py``
"""

import argparse
import time

import numpy as np
from sim_bridge.bullet import bullet_client, pybullet
from sim_bridge.common.geometry import quaternion_from_matrix
from sim_bridge.kinematics import psm_kinematics

ANCHOR_PYBULLET_IK_S = 1e-3
ANCHOR_PYBULLET_IK_MEDIAN_ERROR_M = 1.6e-3


def rate(fn, repeat):
    start = time.perf_counter()
    for _ in range(repeat):
        fn()
    return repeat / (time.perf_counter() - start)


def pybullet_chain(client, chain):
    """The DH chain as a massless PyBullet multibody; the last link is the tool tip."""
    frames = list(chain.joint_placements()) + [chain.tooltip_offset]
    types = [pybullet.JOINT_REVOLUTE if r else pybullet.JOINT_PRISMATIC
             for r in chain.is_revolute] + [pybullet.JOINT_FIXED]
    n = len(frames)
    body = client.createMultiBody(
        baseMass=0.0,
        linkMasses=[0.01] * n,
        linkCollisionShapeIndices=[-1] * n,
        linkVisualShapeIndices=[-1] * n,
        linkPositions=[F[:3, 3].tolist() for F in frames],
        linkOrientations=[quaternion_from_matrix(F[:3, :3]).tolist() for F in frames],
        linkInertialFramePositions=[[0.0, 0.0, 0.0]] * n,
        linkInertialFrameOrientations=[[0.0, 0.0, 0.0, 1.0]] * n,
        linkParentIndices=list(range(n)),
        linkJointTypes=types,
        linkJointAxis=[[0.0, 0.0, 1.0]] * n)
    return body, n - 1


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--targets', type=int, default=300, help='PyBullet IK targets')
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    psm = psm_kinematics()
    m = 10_000
    Q = rng.uniform(psm.lower, psm.upper, size=(m, psm.n_joints))
    T = psm.fk_batch(Q)

    fk_scalar = rate(lambda: psm.fk(Q[0]), 2000)
    start = time.perf_counter()
    psm.fk_batch(Q)
    fk_batch = m / (time.perf_counter() - start)
    ik_scalar = rate(lambda: psm.ik(T[0], q_ref=Q[0]), 1000)
    start = time.perf_counter()
    Q_ik, reachable = psm.ik_batch(T, q_ref=Q)
    batch_time = time.perf_counter() - start
    ik_batch = m / batch_time
    T_ik = psm.fk_batch(Q_ik)
    closed_err = np.linalg.norm(T_ik[:, :3, 3] - T[:, :3, 3], axis=1)

    client = bullet_client.BulletClient(connection_mode=pybullet.DIRECT)
    body, tip = pybullet_chain(client, psm)
    errors, times = [], []
    for q in Q[:args.targets]:
        start_q = q + rng.normal(0.0, 0.02, size=q.shape) * np.where(psm.is_revolute, 1.0, 0.1)
        for j, value in enumerate(start_q):
            client.resetJointState(body, j, value)
        target = T[len(errors)]
        quat = quaternion_from_matrix(target[:3, :3]).tolist()
        t0 = time.perf_counter()
        q_pb = client.calculateInverseKinematics(body, tip, target[:3, 3].tolist(), quat)
        times.append(time.perf_counter() - t0)
        errors.append(np.linalg.norm(psm.fk(np.array(q_pb))[:3, 3] - target[:3, 3]))
    client.disconnect()
    pb_time = float(np.median(times))
    pb_err = np.array(errors)

    print(f'chain: {psm.name}')
    print(f'FK   scalar {fk_scalar:12,.0f} /s')
    print(f'FK   batch  {fk_batch:12,.0f} /s  ({m} poses)')
    print(f'IK   scalar {ik_scalar:12,.0f} /s  ({1e6 / ik_scalar:.0f} us per call)')
    print(f'IK   batch  {ik_batch:12,.0f} /s  ({m} round trips in {batch_time * 1e3:.0f} ms, '
          f'all reachable: {bool(reachable.all())}, max tip error {closed_err.max():.1e} m)')
    print(f'PyBullet calculateInverseKinematics on the same chain: {pb_time * 1e6:.0f} us per '
          f'call, tip error median {np.median(pb_err) * 1e3:.3f} mm, '
          f'p95 {np.percentile(pb_err, 95) * 1e3:.3f} mm ({len(pb_err)} targets)')
    print(f'anchor (SurRoL PSM): {ANCHOR_PYBULLET_IK_S * 1e6:.0f} us per call, median '
          f'{ANCHOR_PYBULLET_IK_MEDIAN_ERROR_M * 1e3:.1f} mm')
    print(f'ratios: closed-form scalar IK is {ik_scalar * pb_time:.1f}x the PyBullet call rate, '
          f'batch {ik_batch * pb_time:.0f}x; vs anchor: scalar '
          f'{ik_scalar * ANCHOR_PYBULLET_IK_S:.1f}x, batch {ik_batch * ANCHOR_PYBULLET_IK_S:.0f}x')


if __name__ == '__main__':
    main()
