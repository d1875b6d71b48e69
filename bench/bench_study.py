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
issue's target: within 10 %) and the ratio of CPU per job after/before.

Designs: ``--quick`` (the default; both methods: 8 demonstrations + 64 throws); ``--full``, the
default study (80 demonstrations + 1,280 throws, both methods: the issue's target is ``local`` in
180 s on two cores); ``--subjects N``, the default study's pairs and methods for N subjects (one
per group first): the same mix of demonstrations and throws as the default study (16 throws per
demonstration), so its CPU per job is the default study's, and the default study's wall time is
estimated from it (``est. full s``: wall time per job times the default study's 1,360 jobs, an
overestimate by the report and start-up time, which do not grow with the jobs).

``--physical L`` measures physical mode instead (issue target: CPU per job at most 1.5x ground
truth): the design's ground-truth study, then the same design with ``--physical --error-level
L`` in the same folder, so that it runs only its physical-mode jobs (the ground-truth ones are
reused); each row's CPU per job is over the jobs it ran, and the ratio physical / ground truth
is printed (``--correction off`` among ``--args`` for open loop).

``--tissue PRESET`` measures the needle-in-tissue realism (issue target: CPU per throw in ground
truth at most 1.3x): the design without it, then with ``--tissue PRESET``, each in its own
folder; the ratio of the mean CPU per executed throw (``cpu_s`` of the records) is printed.

With ``--physical L --before REF`` the same rows run on the code of ``REF`` too (its own
ground truth and physical rows, in one run with these), and the ratios now / before print.

Usage: ``python bench/bench_study.py [--workers 2] [--full | --subjects N] [--before REF]
[--engines local dask] [--physical L] [--tissue PRESET]``
"""

import argparse
import json
import os
from pathlib import Path
import platform
import resource
import subprocess
import sys
import tempfile
import time

from before_revision import REPO, code_env, measure_before

QUICK = ['--quick']
FULL = []
TARGET_FULL_S = 180.0
FULL_JOBS = 80 + 1280  # demonstrations + throws of the default study


def _machine():
    """CPU model, cores and load average (the machine may be shared)."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path('/proc/cpuinfo').read_text().splitlines():
            if line.startswith('model name'):
                model = line.split(':', 1)[1].strip()
                break
    except OSError:
        pass
    load = ', '.join(f'{x:.2f}' for x in os.getloadavg())
    return f'{model}, {os.cpu_count()} CPUs, load average {load}'


def _children_cpu():
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run(label, design, workers, engine='local', code=None, folder=None):
    """
    Run one study; return its wall time, jobs and CPU.

    ``folder``: the report folder to run in (default a new temporary one); only the jobs this
    run adds to its results file are counted.
    """
    with tempfile.TemporaryDirectory() as scratch:
        tmp = str(folder) if folder is not None else scratch
        before = _stored(tmp)
        cmd = [sys.executable, '-m', 'suture_lfd.cli', 'study', '--out', tmp, *design,
               '--workers', str(workers)]
        if engine != 'local':
            cmd += ['--engine', engine]
        env = code_env(code)
        cpu0, t0 = _children_cpu(), time.perf_counter()
        # ``python -m`` puts the working directory first on sys.path: run in the code's tree
        result = subprocess.run(cmd, capture_output=True, text=True, env=env,
                                cwd=str(code if code is not None else REPO))
        wall, cpu = time.perf_counter() - t0, _children_cpu() - cpu0
        if result.returncode != 0:
            raise SystemExit(f'{label}: the study failed:\n{result.stderr[-2000:]}')
        # results.jsonl; results-<hash>.jsonl for a --before revision of the earlier format
        (path,) = [*Path(tmp).glob('results.jsonl'), *Path(tmp).glob('results-*.jsonl')]
        records = [json.loads(line) for line in path.read_text().splitlines()][before:]
    return {'label': label, 'jobs': len(records), 'wall_s': wall, 'cpu_s': cpu,
            'errors': sum(1 for r in records if r.get('error')),
            'simulated_s': sum(r.get('time_s') or 0.0 for r in records)}


def _stored(folder):
    """Records already in a folder's results file (0 for none)."""
    path = Path(folder) / 'results.jsonl'
    return len(path.read_text().splitlines()) if path.exists() else 0


def physical_rows(design, workers, level, realisms=('dvrk',), code=None, prefix=''):
    """
    Ground truth, then physical mode at ``level`` in the same folder (its own jobs only).

    One physical row per arm model of ``realisms`` (``'static'``: the constant offsets of class
    ``level``; a preset of ``config/realism_arm.yaml``), each in the same folder.

    Each row also gets ``throw_cpu_s``: the mean CPU time of its executed throws as their
    worker processes measured it (``cpu_s`` of the records), throws that ran nothing (no
    demonstration to learn from) left out. ``code``: run that tree's code (a ``--before``
    revision), its rows' labels starting with ``prefix``.
    """
    with tempfile.TemporaryDirectory() as tmp:
        ground = run(f'{prefix}ground truth', design, workers, folder=tmp, code=code)
        physical = [run(f'{prefix}physical {m}' + (f' L{level:g}' if m == 'static' else ''),
                        design + ['--physical', '--arm-realism', m]
                        + (['--error-level', f'{level:g}'] if m == 'static' else []),
                        workers, folder=tmp, code=code)
                    for m in realisms]
        records = [json.loads(line)
                   for line in (Path(tmp) / 'results.jsonl').read_text().splitlines()]
    for row, model in ((ground, None), *((p, m) for p, m in zip(physical, realisms))):
        cpu = [r['cpu_s'] for r in records if r['kind'] == 'throw' and r.get('cpu_s') is not None
               and _model(r) == model and r.get('segments')]
        row['throw_cpu_s'] = sum(cpu) / len(cpu) if cpu else float('nan')
        row['throws'] = len(cpu)
    return [ground, *physical]


def _model(record):
    """The arm model of a record (None: ground truth)."""
    phys = record.get('physical')
    if not phys:
        return None
    return phys.get('arm_realism', 'static') if isinstance(phys, dict) else 'static'


def _throw_cpu(records):
    """Mean CPU (s) of the executed throws of ``records`` as their workers measured it."""
    cpu = [r['cpu_s'] for r in records if r['kind'] == 'throw' and r.get('cpu_s') is not None
           and r.get('segments')]
    return (sum(cpu) / len(cpu) if cpu else float('nan')), len(cpu)


def tissue_rows(design, workers, preset):
    """The design without the needle-in-tissue realism, then with ``--tissue preset``."""
    rows = []
    for label, extra in (('tissue none', []), (f'tissue {preset}', ['--tissue', preset])):
        with tempfile.TemporaryDirectory() as tmp:
            row = run(label, design + extra, workers, folder=tmp)
            records = [json.loads(line)
                       for line in (Path(tmp) / 'results.jsonl').read_text().splitlines()]
        row['throw_cpu_s'], row['throws'] = _throw_cpu(records)
        rows.append(row)
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--workers', type=int, default=2)
    parser.add_argument('--engines', nargs='+', default=['local', 'dask'])
    design = parser.add_mutually_exclusive_group()
    design.add_argument('--full', action='store_true',
                        help='the default design (both methods) instead of --quick')
    design.add_argument('--subjects', type=int, default=None,
                        help="the default design for this many subjects (the default study's "
                             'mix of jobs; estimates its wall time)')
    parser.add_argument('--before', default=None,
                        help='git revision whose code runs the same design (local engine)')
    parser.add_argument('--physical', type=float, default=None, metavar='L',
                        help='compare physical mode at error level L with ground truth '
                             '(instead of the engines)')
    parser.add_argument('--tissue', default=None, metavar='PRESET',
                        help='measure the needle-in-tissue preset against none')
    parser.add_argument('--arm-realism', nargs='+', default=['static', 'dvrk'],
                        help='with --physical: the arm models to run (static: the offsets of '
                             'class L; a preset of config/realism_arm.yaml); the CPU per job '
                             'of each is printed against the first')
    parser.add_argument('--args', nargs=argparse.REMAINDER, default=[],
                        help='more study options (e.g. --methods paper)')
    args = parser.parse_args()
    if args.subjects is not None:
        design = ['--subjects', str(args.subjects)] + args.args
    else:
        design = (FULL if args.full else QUICK) + args.args
    machine = _machine()
    if args.physical is not None:
        rows = physical_rows(design, args.workers, args.physical, args.arm_realism)
    elif args.tissue is not None:
        rows = tissue_rows(design, args.workers, args.tissue)
    else:
        rows = [run(e, design, args.workers, engine=e) for e in args.engines]
    before_physical = []
    if args.before and args.physical is not None:
        before_physical = measure_before(args.before, lambda code: physical_rows(
            design, args.workers, args.physical, args.arm_realism, code=code,
            prefix='before '))
        rows += before_physical
    elif args.before:
        rows.append(measure_before(
            args.before, lambda code: run(f'before ({args.before})', design, args.workers,
                                          code=code)))
    estimate = args.full or args.subjects is not None
    print(f'design: {" ".join(design) or "default"}, {args.workers} workers')
    print(f'machine at the start: {machine}')
    print(f'machine at the end:   {_machine()}')
    print(f'{"run":<22} {"jobs":>5} {"wall s":>8} {"jobs/s":>7} {"CPU s/job":>9} '
          f'{"real-time x":>11}' + (f' {"est. full s":>11}' if estimate else ''))
    for r in rows:
        print(f'{r["label"]:<22} {r["jobs"]:>5} {r["wall_s"]:>8.1f} '
              f'{r["jobs"] / r["wall_s"]:>7.2f} {r["cpu_s"] / r["jobs"]:>9.3f} '
              f'{r["simulated_s"] / r["wall_s"]:>11.2f}'
              + (f' {r["wall_s"] / r["jobs"] * FULL_JOBS:>11.0f}' if estimate else '')
              + (f'  ({r["errors"]} jobs raised errors)' if r['errors'] else ''))
    by = {r['label']: r for r in rows}
    if 'local' in by and 'dask' in by:
        print(f'dask / local wall time: {by["dask"]["wall_s"] / by["local"]["wall_s"]:.3f} '
              '(target <= 1.10)')
    if args.physical is not None:
        g, p, *more = rows[:len(rows) - len(before_physical)]
        for q in more:
            print(f'CPU per job, {q["label"]} / {p["label"]}: '
                  f'{(q["cpu_s"] / q["jobs"]) / (p["cpu_s"] / p["jobs"]):.3f} (target <= 1.20)')
        print(f'CPU per job, physical / ground truth: {p["cpu_s"] / p["jobs"]:.3f} / '
              f'{g["cpu_s"] / g["jobs"]:.3f} s = '
              f'{(p["cpu_s"] / p["jobs"]) / (g["cpu_s"] / g["jobs"]):.3f} (target <= 1.50; '
              'the two runs mix demonstrations and throws alike only when every job runs)')
        print(f'CPU per executed throw (in its worker), physical / ground truth: '
              f'{p["throw_cpu_s"]:.3f} ({p["throws"]}) / {g["throw_cpu_s"]:.3f} '
              f'({g["throws"]}) s = {p["throw_cpu_s"] / g["throw_cpu_s"]:.3f}')
        if before_physical:
            bg, bp = before_physical[:2]
            print(f'before ({args.before}): CPU per job, physical / ground truth: '
                  f'{bp["cpu_s"] / bp["jobs"]:.3f} / {bg["cpu_s"] / bg["jobs"]:.3f} s = '
                  f'{(bp["cpu_s"] / bp["jobs"]) / (bg["cpu_s"] / bg["jobs"]):.3f}')
            for now, then in zip(rows, before_physical):
                print(f'CPU per job, {now["label"]} now / before: '
                      f'{(now["cpu_s"] / now["jobs"]) / (then["cpu_s"] / then["jobs"]):.3f}')
    if args.tissue is not None:
        off, on = rows
        print(f'CPU per executed throw (in its worker), tissue {args.tissue} / none: '
              f'{on["throw_cpu_s"]:.3f} ({on["throws"]}) / {off["throw_cpu_s"]:.3f} '
              f'({off["throws"]}) s = {on["throw_cpu_s"] / off["throw_cpu_s"]:.3f} '
              '(target <= 1.30)')
    before = [r for r in rows if r['label'].startswith('before')]
    if before and 'local' in by:
        b, a = before[0], by['local']
        print(f'CPU per job, now / before: {a["cpu_s"] / a["jobs"]:.3f} / '
              f'{b["cpu_s"] / b["jobs"]:.3f} s = '
              f'{(a["cpu_s"] / a["jobs"]) / (b["cpu_s"] / b["jobs"]):.3f}')
    if estimate and 'local' in by:
        full = by['local']['wall_s'] / by['local']['jobs'] * FULL_JOBS
        how = 'measured' if args.full else f'estimated from {by["local"]["jobs"]} jobs'
        print(f'default study on the local engine: {full:.0f} s ({how}; '
              f'{full / TARGET_FULL_S:.2f}x the {TARGET_FULL_S:.0f} s target)')
    print('real-time x: simulated throw seconds per wall second (the paper ran its throws in a '
          'real-time simulator: 1.0)')


if __name__ == '__main__':
    main()
