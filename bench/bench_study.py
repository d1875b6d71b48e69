"""
Throughput of ``suture-lfd study``: throws per second with 1 and 2 workers, and the default
study's extrapolated wall time.

Anchor: the seed paper ran its throws in a real-time simulator, so one simulated second of a
throw cost one wall second. Each run here is a small study (``--quick``, one subject, both
phantoms, the paper's method: 4 demonstrations and 8 throws, all simulated in full); the script
prints throws per second, the real-time factor (simulated throw seconds per wall second, the
anchor being 1.0), the mean wall time of one demonstration and of one throw (from the study's
own records), the speed-up of 2 workers over 1, and the wall time the default study
(80 demonstrations + 640 throws per method) would take at those per-job times, against the
issue's target of 10 minutes.

With ``--full`` it also runs the default design for one method (80 demonstrations and 640
throws) and reports its wall time: the issue's target is that run in 10 minutes.

Usage: ``python bench/bench_study.py [--workers 1 2] [--full] [--args ...]``
"""

import argparse
import json
from pathlib import Path
import subprocess
import sys
import tempfile
import time

SMALL = ['--quick', '--subjects', '1', '--methods', 'paper']
FULL = ['--methods', 'paper']
DEFAULT_DEMOS, DEFAULT_THROWS = 80, 640
TARGET_S = 600.0


def run(workers, extra, design=SMALL):
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, '-m', 'suture_lfd.cli', 'study', '--out', tmp, *design,
               '--workers', str(workers), *extra]
        t0 = time.perf_counter()
        result = subprocess.run(cmd, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if result.returncode != 0:
            raise SystemExit(result.stderr[-2000:])
        (path,) = Path(tmp).glob('results-*.jsonl')
        records = [json.loads(line) for line in path.read_text().splitlines()]
    simulated = sum(r.get('time_s') or 0.0 for r in records)

    def mean_wall(kind):
        times = [r['wall_s'] for r in records if r.get('kind') == kind and 'wall_s' in r]
        return sum(times) / len(times) if times else float('nan')

    return {'workers': workers, 'jobs': len(records), 'wall_s': wall,
            'rate': len(records) / wall, 'simulated_s': simulated,
            'demo_s': mean_wall('demo'), 'throw_s': mean_wall('throw'),
            'errors': sum(1 for r in records if r.get('error'))}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--workers', type=int, nargs='+', default=[1, 2])
    parser.add_argument('--full', action='store_true',
                        help='also run the default design for one method (about 9 min on two '
                             'cores) with the last --workers count and report its wall time')
    parser.add_argument('--args', nargs=argparse.REMAINDER, default=[])
    args = parser.parse_args()
    results = [run(w, args.args) for w in args.workers]
    print(f'{"workers":>7} {"jobs":>5} {"wall s":>8} {"throws/s":>9} {"real-time x":>11} '
          f'{"demo s":>7} {"throw s":>7}')
    for r in results:
        rt = r['simulated_s'] / r['wall_s']
        print(f'{r["workers"]:>7} {r["jobs"]:>5} {r["wall_s"]:>8.1f} {r["rate"]:>9.3f} '
              f'{rt:>11.2f} {r["demo_s"]:>7.2f} {r["throw_s"]:>7.2f}'
              + (f'  ({r["errors"]} jobs raised errors)' if r['errors'] else ''))
    one = results[0]
    serial = DEFAULT_DEMOS * one['demo_s'] + DEFAULT_THROWS * one['throw_s']
    print(f'default study, one method, from the per-job times of {one["workers"]} worker(s): '
          f'{serial / 60:.1f} min of work ({serial / TARGET_S:.1f}x the 10 min target on one '
          'core)')
    if len(results) > 1:
        speedup = results[-1]['rate'] / results[0]['rate']
        print(f'speed-up of {results[-1]["workers"]} workers over {results[0]["workers"]}: '
              f'{speedup:.2f}x; default study at that speed-up: {serial / speedup / 60:.1f} min '
              f'({serial / speedup / TARGET_S:.1f}x the target)')
        print('  (a small study is dominated by start-up: worker processes, first scenes and '
              'skills; --full measures the default design)')
    if args.full:
        full = run(args.workers[-1], args.args, design=FULL)
        print(f'default design, one method, {full["workers"]} worker(s): {full["jobs"]} jobs in '
              f'{full["wall_s"]:.0f} s = {full["wall_s"] / 60:.1f} min '
              f'({full["wall_s"] / TARGET_S:.2f}x the 10 min target), {full["rate"]:.2f} jobs/s, '
              f'demo {full["demo_s"]:.2f} s, throw {full["throw_s"]:.2f} s per job'
              + (f', {full["errors"]} jobs raised errors' if full['errors'] else ''))
    print("real-time x: simulated throw seconds per wall second (anchor: the paper's "
          'real-time simulator = 1.0); demo s / throw s: mean wall time of one job (the '
          "study's records)")


if __name__ == '__main__':
    main()
