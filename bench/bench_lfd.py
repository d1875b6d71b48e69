"""
LfD core speed: pose DMP fit + rollout and DTW, side by side with public libraries.

Workload (lfd_anchors section 3.0): a synthetic needle throw of 500 samples on t in [0, 1] s,
200 degrees of needle turn, 100 basis functions per dimension (position and orientation).

Anchors (lfd_anchors section 3, 2 Xeon cores): movement_primitives 0.9.1 ``CartesianDMP`` 53 ms
fit + 42 ms rollout (``int_dt`` 1 ms); dtaidistance 2.5.1 ``dtw_ndim.distance_fast`` (C) 1.1 ms
and ``warping_path(use_c=True)`` 1.5 ms on 500x500 3-D trajectories. When movement_primitives
or dtaidistance can be imported (they are not project dependencies; install them beside the
benchmark), they run here in the same process on the same data and the ratios are against
those measurements; otherwise against the anchor numbers.

Targets (issue): fit + rollout <= 2 ms (>= 40x faster than movement_primitives), DTW <= 1 ms.

Times are the fastest of ``--repeat`` calls (``timeit``'s convention: the run least disturbed by
other load on the machine), for ours and for the libraries alike.

Run: ``.venv/bin/python bench/bench_lfd.py``
"""

import argparse
import time

import numpy as np
from sim_bridge.common.geometry import quaternion_angle
from suture_lfd.demos.synthetic_throw import needle_throw
from suture_lfd.dmp import DmpParams, PoseDmp
from suture_lfd.study.metrics import (
    dtw_distance,
    dtw_path,
    orientation_trajectory_error,
    trajectory_error,
)

ANCHOR_MP_FIT_S = 53e-3
ANCHOR_MP_ROLLOUT_S = 42e-3
ANCHOR_DTAI_DISTANCE_S = 1.1e-3
ANCHOR_DTAI_PATH_S = 1.5e-3
TARGET_DMP_S = 2e-3
TARGET_DTW_S = 1e-3


def best_time(fn, repeat):
    """Fastest wall time (s) of ``repeat`` calls after one warm-up call; returns (time, result)."""
    result = fn()
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return min(times), result


def ours_dmp(T, P, Q, repeat):
    params = DmpParams(n_bfs=100, n_bfs_o=100, n_pts=T.size)
    fit_s, dmp = best_time(lambda: PoseDmp(params).fit(T, P, Q), repeat)
    roll_s, (_, P_out, Q_out) = best_time(dmp.rollout, repeat)
    return fit_s, roll_s, P_out, Q_out


def movement_primitives_dmp(T, P, Q, repeat):
    try:
        from movement_primitives.dmp import CartesianDMP
    except ImportError:
        return None
    Y = np.column_stack((P, Q[:, [3, 0, 1, 2]]))  # pytransform3d orders quaternions (w, x, y, z)

    def fit():
        dmp = CartesianDMP(execution_time=float(T[-1]), dt=float(T[1] - T[0]),
                           n_weights_per_dim=100, int_dt=0.001)
        dmp.imitate(T, Y)
        dmp.configure(start_y=Y[0], goal_y=Y[-1])
        return dmp

    fit_s, dmp = best_time(fit, repeat)
    roll_s, (_, Y_out) = best_time(dmp.open_loop, repeat)
    return fit_s, roll_s, Y_out[:, :3], Y_out[:, [4, 5, 6, 3]]


def dtaidistance_dtw(A, B, repeat):
    try:
        from dtaidistance import dtw, dtw_ndim
    except ImportError:
        return None
    if not dtw.try_import_c():
        return None
    a, b = np.ascontiguousarray(A), np.ascontiguousarray(B)
    dist_s, _ = best_time(lambda: dtw_ndim.distance_fast(a, b), repeat)
    path_s, path = best_time(lambda: dtw_ndim.warping_path(a, b, use_c=True), repeat)
    return dist_s, path_s, np.asarray(path)


def accuracy(P, Q, P_out, Q_out):
    pos = trajectory_error(P, P_out)
    ori = orientation_trajectory_error(Q, Q_out)
    goal_mm = 1e3 * float(np.linalg.norm(P_out[-1] - P[-1]))
    goal_deg = float(np.degrees(quaternion_angle(Q_out[-1], Q[-1])))
    return (f'position mean {pos["mean_mm"]:.3f} / max {pos["max_mm"]:.3f} mm, goal '
            f'{goal_mm:.4f} mm; orientation mean {ori["mean_deg"]:.2f} / max '
            f'{ori["max_deg"]:.2f} deg, goal {goal_deg:.3f} deg')


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--repeat', type=int, default=30)
    args = parser.parse_args()
    T, P, Q = needle_throw(500, 1.0, rotation_deg=200.0)
    rng = np.random.default_rng(0)

    print('DMP fit + rollout: position + quaternion, 500 points, 100 basis functions per dim')
    fit_s, roll_s, P_out, Q_out = ours_dmp(T, P, Q, args.repeat)
    ours = fit_s + roll_s
    print(f'  ours                 fit {fit_s * 1e3:7.2f} ms  rollout {roll_s * 1e3:7.2f} ms  '
          f'total {ours * 1e3:7.2f} ms   {accuracy(P, Q, P_out, Q_out)}')
    mp = movement_primitives_dmp(T, P, Q, max(3, args.repeat // 3))
    if mp is not None:
        mp_fit, mp_roll, mP, mQ = mp
        print(f'  movement_primitives  fit {mp_fit * 1e3:7.2f} ms  rollout {mp_roll * 1e3:7.2f} '
              f'ms  total {(mp_fit + mp_roll) * 1e3:7.2f} ms   {accuracy(P, Q, mP, mQ)}')
        ref, ref_name = mp_fit + mp_roll, 'movement_primitives measured in this run'
    else:
        ref, ref_name = ANCHOR_MP_FIT_S + ANCHOR_MP_ROLLOUT_S, \
            'movement_primitives anchor (53 + 42 ms; not importable here)'
    print(f'  anchor               fit {ANCHOR_MP_FIT_S * 1e3:7.2f} ms  rollout '
          f'{ANCHOR_MP_ROLLOUT_S * 1e3:7.2f} ms  total '
          f'{(ANCHOR_MP_FIT_S + ANCHOR_MP_ROLLOUT_S) * 1e3:7.2f} ms (lfd_anchors 3.1)')
    print(f'  ratio: ours is {ref / ours:.1f}x faster than {ref_name}; '
          f'{(ANCHOR_MP_FIT_S + ANCHOR_MP_ROLLOUT_S) / ours:.1f}x vs the anchor numbers; '
          f'target <= {TARGET_DMP_S * 1e3:.0f} ms: {"met" if ours <= TARGET_DMP_S else "NOT met"} '
          f'({ours / TARGET_DMP_S:.2f}x the target time)')

    print('DTW: 500 x 500 3-D trajectories (exact DP, Euclidean local cost)')
    A = P
    B = P_out + rng.normal(0.0, 1e-4, P_out.shape)
    dist_s, total = best_time(lambda: dtw_distance(A, B), args.repeat)
    path_s, (path, _) = best_time(lambda: dtw_path(A, B), args.repeat)
    print(f'  ours                 distance {dist_s * 1e3:7.3f} ms  path {path_s * 1e3:7.3f} ms '
          f'(sum |.| = {total:.5f} m, {len(path)} pairs)')
    dt = dtaidistance_dtw(A, B, args.repeat)
    if dt is not None:
        d_dist, d_path, d_p = dt
        print(f'  dtaidistance C       distance {d_dist * 1e3:7.3f} ms  path {d_path * 1e3:7.3f} '
              f'ms ({len(d_p)} pairs; its distance is sqrt sum |.|^2)')
        ref_d, ref_p, ref_name = d_dist, d_path, 'dtaidistance C measured in this run'
    else:
        ref_d, ref_p, ref_name = ANCHOR_DTAI_DISTANCE_S, ANCHOR_DTAI_PATH_S, \
            'dtaidistance anchor (1.1 / 1.5 ms; not importable here)'
    print(f'  anchor               distance {ANCHOR_DTAI_DISTANCE_S * 1e3:7.3f} ms  path '
          f'{ANCHOR_DTAI_PATH_S * 1e3:7.3f} ms (lfd_anchors 3.2)')
    print(f'  ratio vs {ref_name}: distance {ref_d / dist_s:.2f}x, path {ref_p / path_s:.2f}x '
          f'(>1: ours faster); vs the anchor numbers: distance '
          f'{ANCHOR_DTAI_DISTANCE_S / dist_s:.2f}x, path {ANCHOR_DTAI_PATH_S / path_s:.2f}x; '
          f'target <= {TARGET_DTW_S * 1e3:.0f} ms: '
          f'{"met" if dist_s <= TARGET_DTW_S else "NOT met"} ({dist_s / TARGET_DTW_S:.2f}x the '
          f'target time)')


if __name__ == '__main__':
    main()
