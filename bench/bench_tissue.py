"""Time TissueTracker.update and the phantom containment query against the 50 us budget."""

import time

import numpy as np
from sim_bridge.scene.scene_config import load_scene_config
from sim_bridge.scene.tissue import TissueTracker
from suture_lfd.planning.throw_geometry import ThrowArc

BUDGET_US = 50.0


def per_call(fn, n):
    fn()
    start = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - start) / n * 1e6


def main():
    scene = load_scene_config()
    for name in ('synthetic', 'scanned'):
        phantom = scene.build_phantom(name)
        pair = next(iter(phantom.markers.values()))
        arc = ThrowArc(pair, scene.needle)
        poses = [arc.T_world_needle(a) for a in
                 np.linspace(arc.alpha_entry + 0.3, arc.alpha_through - 0.3, 4000)]
        tracker = TissueTracker(phantom, scene.needle, scene.tissue)
        tracker.set_target_pair(pair.name)
        start = time.perf_counter()
        for k, T in enumerate(poses):
            tracker.update(k * 0.001, T)
        throw_us = (time.perf_counter() - start) / len(poses) * 1e6
        pts = scene.needle.points_world(poses[len(poses) // 2], scene.tissue.n_arc_points)
        query_us = per_call(lambda p=phantom, q=pts: p.is_inside(q), 20000)
        print(f'{name:9s} update {throw_us:6.1f} us/step over a full throw '
              f'({throw_us / BUDGET_US:.2f} of the {BUDGET_US:.0f} us budget); '
              f'is_inside({len(pts)} points) {query_us:5.1f} us')


if __name__ == '__main__':
    main()
