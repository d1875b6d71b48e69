"""
The lying needle's detected pose on both pads, with and without the triangulated centre line.

Scenes (:class:`suture_lfd.perception.evaluation.SceneMaker`, kind ``free``): the needle where
the simulation's reset leaves it on the synthetic (flat) and the scanned (curved) pad. The
tracker detects it without a prior, given the markers' plane as the support, twice on the same
images: as the anchor, the image fit alone (the default); then with ``centre_line``, the fits
moved onto the wire's triangulated centre line (:mod:`suture_lfd.perception.arc_stereo`) before
the edges refine them.

Metrics against the simulation's truth (measured here, never given to the tracker): the share
found; the largest of the base, middle and tip errors (mm) and the orientation error (deg) of
the best pose, found or not (median and 90th percentile); confident but wrong (found, a point
more than 3 mm off); CPU per detection (one core, ``time.process_time``) and its ratio to the
anchor's.

``--physics-step 0.01``: the scenes settled at the study's physics step (the needle then rests
a few hundredths of a millimetre deeper into the pad) instead of ``world.yaml``'s 2 ms.
``--resting``: the needle where a scene reset leaves it (a study's start), each scene on its own
3 mm-class robot (its instruments elsewhere in view), instead of placed at random.

A third row gives the anchor's tracker the markers' centroid as well (``support_point``): the
detection then also starts from the needle's blobs laid on the markers' plane, as the physical
mode's perception does.

Run: ``.venv/bin/python bench/bench_lying_needle.py [--scenes 12] [--seed 3]
[--physics-step 0.01] [--resting]``.
"""

import argparse
from dataclasses import replace
import math
import os
import time

import numpy as np
from suture_lfd.perception import NeedleTracker, detect_markers
from suture_lfd.perception.evaluation import SceneMaker, needle_errors

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')  # no ROS here; house rule

WRONG = 0.003  # a found estimate with a point farther off than this is wrong


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--scenes', type=int, default=12, help='scenes per pad')
    parser.add_argument('--seed', type=int, default=3)
    parser.add_argument('--physics-step', type=float, default=None,
                        help="physics step (s) the scenes settle at (default world.yaml's)")
    parser.add_argument('--resting', action='store_true',
                        help='the needle where a reset leaves it, each scene on its own '
                             '3 mm-class robot')
    args = parser.parse_args()
    anchor = NeedleTracker()
    trackers = {'image fit (anchor)': (anchor, False),
                'centre line + image fit': (NeedleTracker(
                    config=replace(anchor.config, centre_line=True)), False),
                'image fit + marker point': (anchor, True)}
    head = (f'{"pad":10} {"detection":24} {"found":>6} {"max mm":>7} {"p90 mm":>7} {"deg":>5} '
            f'{"p90 deg":>7} {"wrong":>6} {"CPU ms":>7} {"CPU/anchor":>10}')
    print(head)
    print('-' * len(head))
    for phantom in ('synthetic', 'scanned'):
        maker = None if args.resting else SceneMaker(phantom, physics_step=args.physics_step)
        rng = np.random.default_rng(args.seed)
        rows = {name: [] for name in trackers}
        done = 0
        while done < args.scenes:
            if args.resting:
                if maker is not None:
                    maker.close()
                robot = (3.0, int(rng.integers(1 << 31)))
                maker = SceneMaker(phantom, physics_step=args.physics_step,
                                   kinematic_errors=robot)
                scene = maker.resting(int(rng.integers(1 << 31)))
            else:
                scene = maker.scene('free', rng)
            if scene is None:
                continue
            done += 1
            markers = detect_markers(scene.left, scene.right, scene.stereo)
            for name, (tracker, with_point) in trackers.items():
                start = time.process_time()
                est = tracker.estimate(scene.left, scene.right, scene.stereo,
                                       support_normal=markers.normal,
                                       support_point=markers.points.mean(axis=0)
                                       if with_point else None)
                cpu = time.process_time() - start
                _, largest, angle = needle_errors(est.pose_camera, scene.T_camera_needle,
                                                  tracker.geometry)
                rows[name].append((est.found, largest, angle, cpu))
        if maker is not None:
            maker.close()
        anchor_cpu = None
        for name, r in rows.items():
            a = np.array(r, dtype=float)
            cpu = float(np.median(a[:, 3]))
            anchor_cpu = anchor_cpu or cpu
            wrong = int(np.sum((a[:, 0] > 0) & (a[:, 1] > WRONG)))
            print(f'{phantom:10} {name:24} {a[:, 0].mean():6.0%} '
                  f'{1e3 * np.median(a[:, 1]):7.2f} {1e3 * np.percentile(a[:, 1], 90):7.2f} '
                  f'{math.degrees(np.median(a[:, 2])):5.1f} '
                  f'{math.degrees(np.percentile(a[:, 2], 90)):7.1f} {wrong:6d} '
                  f'{1e3 * cpu:7.0f} {cpu / anchor_cpu:10.2f}')
    print('max mm: the largest of the base, middle and tip errors, of the best pose found or '
          'not; wrong: found with a point > 3 mm off')


if __name__ == '__main__':
    main()
