"""
Needle in tissue: the tracker's cost per step, and how often the needle turns in the jaw.

``python bench/bench_tissue.py`` times ``TissueTracker.update`` and the phantom containment
query against the 50 us budget.

``python bench/bench_tissue.py --slips [--seeds N] [--methods paper,pair_frame] [--grips
1,3.3]`` learns each method's skill from one scripted demonstration on ``synth1`` and executes
it on every pair of the synthetic phantom, ``N`` seeds each, without the needle-in-tissue
realism and with the ``tissue`` preset at each grip level (1: the preset; 3.3: the weakest
needle holder of the preset's source), the same throws side by side in one process. It prints,
per method and setting: the generality (mean score), the per-subtask success, how many throws
slipped and in which subtask (by the time of the slip within the executed subtask spans), how
many of the slipped throws the executor saved (complete all the same) and how many broke the
grasp.
"""

import argparse
from collections import Counter
from dataclasses import replace
from pathlib import Path
import tempfile
import time

import numpy as np
from sim_bridge.common.vocabulary import SUBTASKS
from sim_bridge.realism.tissue_config import load_tissue_realism
from sim_bridge.scene.scene_config import load_scene_config
from sim_bridge.scene.tissue import TissueTracker
from sim_bridge.simulation import Simulation, load_simulation_config
from suture_lfd.demos.scripted_demo import record_scripted_demonstration
from suture_lfd.demos.segment_file import make_segment_file
from suture_lfd.planning.throw_geometry import ThrowArc
from suture_lfd.segmentation import segment_demonstration
from suture_lfd.skill import learn_skill
from suture_lfd.skill.executor import execute_throw

BUDGET_US = 50.0


def per_call(fn, n):
    fn()
    start = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - start) / n * 1e6


def tracker_rows():
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


def slip_subtask(t, t0, spans):
    """Subtask whose executed span holds the slip at simulated time ``t`` (``'?'`` if none)."""
    for label, (a, b) in spans.items():
        if a <= t - t0 <= b + 0.05:
            return label
    return '?'


def run_throws(sim, skill, pairs, seeds):
    """Execute ``skill`` on every pair and seed; return one dict per throw."""
    rows = []
    for pair in pairs:
        for seed in seeds:
            start = []
            outcome = execute_throw(sim, skill, pair, seed=seed,
                                    observer=lambda s=sim, c=start: c or c.append(s.time))
            t0 = start[0] if start else 0.0
            slips = [e for e in outcome.events if e['kind'] == 'slip']
            rows.append({'pair': pair, 'seed': seed, 'score': outcome.score,
                         'subtasks': outcome.subtasks, 'failure': outcome.failure,
                         'slips': [(slip_subtask(e['t'], t0, outcome.subtask_times),
                                    float(e['angle']), bool(e['broken'])) for e in slips]})
    return rows


def summary(rows):
    """One printed line of generality, subtask success and slips for a set of throws."""
    n = len(rows)
    generality = float(np.mean([r['score'] for r in rows]))
    per_sub = {s: sum(r['subtasks'][s] for r in rows) for s in SUBTASKS}
    slipped = [r for r in rows if r['slips']]
    where = Counter(label for r in slipped for label in {s for s, _, _ in r['slips']})
    saved = sum(r['score'] == 1.0 for r in slipped)
    broken = sum(any(b for _, _, b in r['slips']) for r in slipped)
    turns = [abs(a) for r in slipped for _, a, _ in r['slips']]
    turn = f', turn median {np.degrees(np.median(turns)):.1f} deg' if turns else ''
    return (f'generality {generality:.3f} over {n} throws; subtasks '
            + ' '.join(f'{s} {per_sub[s]}/{n}' for s in SUBTASKS)
            + f'; slipped {len(slipped)}/{n} (by subtask: '
            + ', '.join(f'{k} {v}' for k, v in sorted(where.items()))
            + f'), saved {saved}/{len(slipped)}, grasp broken {broken}{turn}')


def slip_rows(methods, seeds, grips):
    base = load_simulation_config()
    sim = Simulation(base)
    demo, _, score = record_scripted_demonstration(sim, 'synth1', seed=0)
    pairs = list(sim.phantom.markers)
    sim.close()
    if score.score != 1.0:
        raise RuntimeError(f'the scripted demonstration failed: {score.failure}')
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / 'synth1.npz'
        make_segment_file(demo, segment_demonstration(demo), source='synth1 expert').save(path)
        skills = {m: learn_skill(path, m) for m in methods}
    results = {}
    tissue = load_tissue_realism('tissue')
    settings = [('none', load_tissue_realism('none'))] + [
        ('tissue' if g == 1.0 else f'grip{g:g}', replace(tissue, grip=g)) for g in grips]
    for preset, realism in settings:
        sim = Simulation(replace(base, tissue_realism=realism))
        for method in methods:
            start = time.process_time()
            rows = run_throws(sim, skills[method], pairs, seeds)
            cpu = (time.process_time() - start) / len(rows)
            results[method, preset] = rows
            print(f'{method:10s} {preset:8s} {summary(rows)}; CPU {cpu:.2f} s/throw',
                  flush=True)
        sim.close()
    for method in methods:
        off = np.mean([r['score'] for r in results[method, 'none']])
        for preset, _ in settings[1:]:
            on = np.mean([r['score'] for r in results[method, preset]])
            print(f'{method:10s} generality {preset} / none: {on:.3f} / {off:.3f} = '
                  f'{on / off if off else float("nan"):.3f}')


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0].strip())
    parser.add_argument('--slips', action='store_true',
                        help='count the needle turning in the jaw over executed throws')
    parser.add_argument('--seeds', type=int, default=2, help='seeds per pair (default 2)')
    parser.add_argument('--methods', default='paper,pair_frame')
    parser.add_argument('--grips', default='1',
                        help='grip levels of the tissue preset (default 1: the preset)')
    args = parser.parse_args()
    if args.slips:
        slip_rows(args.methods.split(','), range(args.seeds),
                  [float(g) for g in args.grips.split(',')])
    else:
        tracker_rows()


if __name__ == '__main__':
    main()
