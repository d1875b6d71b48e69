"""
Wall time of ``suture-lfd study`` under each engine, and CPU per job, side by side in one run.

Each row is one whole study run as a user runs it (a subprocess of ``suture-lfd study``):

- ``local``: the process pool (``--engine local``), ``--workers`` processes;
- ``dask``: a local Dask cluster (``--engine dask``) of as many process workers;
- ``before`` (with ``--before REF``): the local pool running the code of git revision ``REF``
  (checked out in a temporary worktree), the per-core anchor of a speed change.

It prints the wall time, jobs per second, CPU seconds per job (the CPU of the study process and
every worker, from ``getrusage(RUSAGE_CHILDREN)``, divided by the jobs: a measure that a loaded
machine disturbs far less than wall time), the ratio of ``dask`` to ``local`` wall time (the
issue's target: within 10 %) and the ratio of CPU per job after/before. The design is a small
study by default (``--quick``, both methods: 8 demonstrations + 64 throws); ``--full`` runs the
default design (80 demonstrations + 1,280 throws, both methods): the issue's target is
``local`` in 180 s on two cores.

Usage: ``python bench/bench_study.py [--workers 2] [--full] [--before REF] [--engines local dask]``
"""

import argparse
import json
import os
from pathlib import Path
import resource
import subprocess
import sys
import tempfile
import time

QUICK = ['--quick']
FULL = []
TARGET_FULL_S = 180.0
REPO = Path(__file__).resolve().parents[1]


def _children_cpu():
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run(label, design, workers, engine='local', code=None):
    """Run one study; return its wall time, jobs and CPU."""
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, '-m', 'suture_lfd.cli', 'study', '--out', tmp, *design,
               '--workers', str(workers)]
        if engine != 'local':
            cmd += ['--engine', engine]
        env = dict(os.environ)
        if code is not None:
            env['PYTHONPATH'] = str(code) + os.pathsep + env.get('PYTHONPATH', '')
        cpu0, t0 = _children_cpu(), time.perf_counter()
        result = subprocess.run(cmd, capture_output=True, text=True, env=env)
        wall, cpu = time.perf_counter() - t0, _children_cpu() - cpu0
        if result.returncode != 0:
            raise SystemExit(f'{label}: the study failed:\n{result.stderr[-2000:]}')
        (path,) = Path(tmp).glob('results-*.jsonl')
        records = [json.loads(line) for line in path.read_text().splitlines()]
    return {'label': label, 'jobs': len(records), 'wall_s': wall, 'cpu_s': cpu,
            'errors': sum(1 for r in records if r.get('error')),
            'simulated_s': sum(r.get('time_s') or 0.0 for r in records)}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--workers', type=int, default=2)
    parser.add_argument('--engines', nargs='+', default=['local', 'dask'])
    parser.add_argument('--full', action='store_true',
                        help='the default design (both methods) instead of --quick')
    parser.add_argument('--before', default=None,
                        help='git revision whose code runs the same design (local engine)')
    parser.add_argument('--args', nargs=argparse.REMAINDER, default=[],
                        help='more study options (e.g. --methods paper)')
    args = parser.parse_args()
    design = (FULL if args.full else QUICK) + args.args
    rows = [run(e, design, args.workers, engine=e) for e in args.engines]
    if args.before:
        with tempfile.TemporaryDirectory() as tmp:
            tree = Path(tmp) / 'before'
            subprocess.run(['git', '-C', str(REPO), 'worktree', 'add', '--detach', str(tree),
                            args.before], check=True, capture_output=True)
            try:
                rows.append(run(f'before ({args.before})', design, args.workers, code=tree))
            finally:
                subprocess.run(['git', '-C', str(REPO), 'worktree', 'remove', '--force',
                                str(tree)], capture_output=True)
    print(f'design: {" ".join(design) or "default"}, {args.workers} workers, '
          f'{os.cpu_count()} CPUs')
    print(f'{"run":<22} {"jobs":>5} {"wall s":>8} {"jobs/s":>7} {"CPU s/job":>9} '
          f'{"real-time x":>11}')
    for r in rows:
        print(f'{r["label"]:<22} {r["jobs"]:>5} {r["wall_s"]:>8.1f} '
              f'{r["jobs"] / r["wall_s"]:>7.2f} {r["cpu_s"] / r["jobs"]:>9.3f} '
              f'{r["simulated_s"] / r["wall_s"]:>11.2f}'
              + (f'  ({r["errors"]} jobs raised errors)' if r['errors'] else ''))
    by = {r['label']: r for r in rows}
    if 'local' in by and 'dask' in by:
        print(f'dask / local wall time: {by["dask"]["wall_s"] / by["local"]["wall_s"]:.3f} '
              '(target <= 1.10)')
    before = [r for r in rows if r['label'].startswith('before')]
    if before and 'local' in by:
        b, a = before[0], by['local']
        print(f'CPU per job, now / before: {a["cpu_s"] / a["jobs"]:.3f} / '
              f'{b["cpu_s"] / b["jobs"]:.3f} s = '
              f'{(a["cpu_s"] / a["jobs"]) / (b["cpu_s"] / b["jobs"]):.3f}')
    if args.full and 'local' in by:
        print(f'default study on the local engine: {by["local"]["wall_s"]:.0f} s '
              f'({by["local"]["wall_s"] / TARGET_FULL_S:.2f}x the {TARGET_FULL_S:.0f} s target)')
    print('real-time x: simulated throw seconds per wall second (the paper ran its throws in a '
          'real-time simulator: 1.0)')


if __name__ == '__main__':
    main()
