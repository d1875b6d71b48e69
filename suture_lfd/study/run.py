"""
``suture-lfd study``: the options, the configuration and jobs of a study, and the run.

The default design is the paper's (Zhou et al., ISMR 2024, Sec. III-C and IV): the cohort of
``config/cohort.yaml`` (10 synthetic subjects, 4 experienced and 6 naive) each demonstrates a
throw on the four marker pairs of each phantom, in order; every demonstration is recorded as a
bag, read back and segmented by the segmenter's code; then, for every method (``paper`` and the
others of :data:`suture_lfd.skill.METHODS`), every subject's skill learnt on each pair is
executed on every pair (the generality matrix, 64 throws per subject; its diagonal is the
regeneration test of Table II). The report folder (``--out``) gets ``report.md`` with the
paper's tables beside ours, PNG figures, ``throws.csv`` / ``demos.csv`` and the configuration.

Long runs print progress; the per-job results are appended to ``results.jsonl`` in the output
folder as they finish, each under its job's ``id`` (:mod:`suture_lfd.study.keys`: the digest of
what decides its result), so running the same command again after an interruption only does
the jobs that are missing, and any other study in the folder (methods reordered or added, more
subjects, held-out pairs) reuses every job it shares with the stored ones. SIGINT and SIGTERM
stop the run (:mod:`suture_lfd.study.signals`): exit status 130 / 143, no report, the stored
results kept. ``--workers N`` runs jobs in N processes.

``--held-out N`` also executes every subject's skills on pairs that are not among the fixed
ones (N random pairs per phantom on its wound line, and on a user mesh with
``--held-out-mesh``) and reports generality on them beside the fixed pairs
(:mod:`suture_lfd.study.held_out`); the fixed pairs' results are unchanged by it.

``--via-ros`` executes every throw through real node processes instead of in-process: per
throw a ``simulator`` node (the job's phantom and seed) and an ``executor`` node with the skill
the study learnt, on a private ROS domain per worker (:mod:`suture_lfd.study.ros`); the
demonstrations stay in-process. Its jobs have other ``id`` s than the in-process ones.
"""

import argparse
from collections.abc import Sequence
import dataclasses
import json
import logging
import os
from pathlib import Path
import shlex
import sys
import time
from typing import IO, TYPE_CHECKING, Any
import zlib

import numpy as np
from suture_lfd.study import held_out, physical
from suture_lfd.study.digest import code_digest, file_digest
from suture_lfd.study.engine import (
    parse_engine,
)
from suture_lfd.study.jobs import JobSettings
from suture_lfd.study.keys import BOOKKEEPING, demo_ids, with_ids
from suture_lfd.study.options import QUICK_PAIRS, QUICK_SUBJECTS
from suture_lfd.study.records import DemoJob, DemoRecord, Record, ThrowJob, ThrowRecord, plan_json
from suture_lfd.study.runner import Progress
from suture_lfd.study.signals import stop_on_signals
from suture_lfd.study.stages import Stage, run_job_stages
from suture_lfd.study.store import ResultStore, config_hash, earlier_format_files

if TYPE_CHECKING:
    from suture_lfd.demos.cohort import Subject

_LOG = logging.getLogger(__name__)
STUDY_FORMAT = 1


# ---------------------------------------------------------------------- configuration
def _pick_subjects(cohort: Sequence['Subject'], count: int | None) -> list['Subject']:
    """Return the first ``count`` subjects taken in turn from each group (all for None)."""
    if count is None or count >= len(cohort):
        return list(cohort)
    if count < 1:
        raise ValueError(f'--subjects must be >= 1, got {count}')
    groups: dict[str, list[Subject]] = {}
    for s in cohort:
        groups.setdefault(s.group, []).append(s)
    picked: list[Subject] = []
    while len(picked) < count:
        for members in groups.values():
            if members and len(picked) < count:
                picked.append(members.pop(0))
    return sorted(picked, key=lambda s: s.name)


def job_seed(study_seed: int, key: str) -> int:
    """Return the scene seed of a job: the same for the same study seed and job key."""
    return int(np.random.SeedSequence([int(study_seed), zlib.crc32(key.encode())])
               .generate_state(1)[0] >> 1)


def build_config(args: argparse.Namespace) -> dict[str, Any]:
    """
    Return the study's exact configuration (a JSON-serialisable dict) from the options.

    Parameters
    ----------
    args : argparse.Namespace
        Options of :func:`suture_lfd.study.options.add_study_arguments`.

    Returns
    -------
    dict
        ``seed``, ``subjects`` (name, group, seed, skill profile), ``phantoms`` (phantom ->
        pairs in order), ``methods``, ``method_descriptions``, settings and file digests.

    """
    from sim_bridge.common.paths import config_path
    from suture_lfd.demos.cohort import load_cohort, load_study_design
    from suture_lfd.skill import METHODS

    if args.seed < 0:
        raise ValueError(f'--seed must be >= 0, got {args.seed}')
    cohort_path = Path(args.cohort).resolve() if args.cohort else config_path('cohort.yaml')
    design = load_study_design(cohort_path)
    cohort = load_cohort(cohort_path, seed=args.seed)
    n_subjects = args.subjects if args.subjects is not None else (
        QUICK_SUBJECTS if args.quick else None)
    n_pairs = args.pairs if args.pairs is not None else (QUICK_PAIRS if args.quick else None)
    if n_pairs is not None and n_pairs < 1:
        raise ValueError(f'--pairs must be >= 1, got {n_pairs}')
    subjects = _pick_subjects(cohort, n_subjects)
    phantoms = {ph: list(pairs[:n_pairs] if n_pairs else pairs)
                for ph, pairs in design.phantoms.items()}
    if args.phantoms:
        chosen = [p.strip() for p in args.phantoms.split(',') if p.strip()]
        unknown = [p for p in chosen if p not in phantoms]
        if unknown or not chosen:
            raise ValueError(f'unknown phantom {unknown[0] if unknown else args.phantoms!r}; '
                             f'--phantoms takes names from {sorted(phantoms)}')
        phantoms = {p: phantoms[p] for p in chosen}
    if args.methods:
        methods = [m.strip() for m in args.methods.split(',') if m.strip()]
        unknown = [m for m in methods if m not in METHODS]
        if unknown:
            raise ValueError(f'unknown method {unknown[0]!r}; --methods takes names from '
                             f'{sorted(METHODS)}')
    else:
        methods = list(METHODS)
    held = held_out.held_out_config(args, phantoms, args.seed)
    physical_mode = physical.physical_config(args)
    tissue = str(getattr(args, 'tissue', 'none'))
    if tissue != 'none':
        from sim_bridge.realism.tissue_config import load_tissue_realism

        load_tissue_realism(tissue)  # a bad name stops here, with the names there are
    camera = str(getattr(args, 'camera', 'none'))
    if camera != 'none':
        from sim_bridge.realism.endoscope import endoscope_preset

        endoscope_preset(camera)  # a bad name stops here, with the names there are
    settings = JobSettings(out='', cohort_path=str(cohort_path), cohort_seed=args.seed,
                           tissue=tissue, camera=camera)
    files = {name: file_digest(config_path(name))
             for name in ('scene.yaml', 'world.yaml', 'dmp.yaml', 'kinematics.yaml')
             if config_path(name).exists()}
    files['cohort'] = file_digest(cohort_path)
    extra = {}
    if getattr(args, 'via_ros', False):
        # throws through the nodes: other results, so another hash (in-process runs keep theirs)
        from suture_lfd.study.ros import RosSettings

        nodes = {k: v for k, v in dataclasses.asdict(RosSettings()).items()
                 if k in ('real_time_factor', 'rate', 'stale_timeout')}
        extra['via_ros'] = {'nodes': nodes,
                            'files': {name: file_digest(config_path(name))
                                      for name in ('simulator.yaml', 'executor.yaml')
                                      if config_path(name).exists()}}
    return {
        'format': STUDY_FORMAT,
        'seed': int(args.seed),
        'quick': bool(args.quick),
        'cohort_file': str(cohort_path),
        'subjects': [{'name': s.name, 'group': s.group, 'seed': s.seed,
                      'profile': dataclasses.asdict(s.profile)} for s in subjects],
        'phantoms': phantoms,
        'methods': methods,
        'method_descriptions': {m: getattr(METHODS[m], 'description', '') for m in methods},
        'assessment': getattr(args, 'assessment', 'subject'),
        'settings': {k: v for k, v in dataclasses.asdict(settings).items()
                     if k not in ('out', 'cohort_path')},
        'files': files,
        'code': code_digest(),
        **extra,
        **({'held_out': held} if held else {}),
        **({'physical': physical_mode} if physical_mode else {}),
    }


def hashed_config(config: dict[str, Any]) -> dict[str, Any]:
    """Return the configuration that decides the results (not paths or descriptions)."""
    # held-out throws are keyed by their geometry: the fixed-pair results stay shared
    return {k: v for k, v in config.items()
            if k not in ('cohort_file', 'method_descriptions', 'quick', 'held_out',
                         'assessment', 'physical')}


def plan_jobs(config: dict[str, Any]) -> tuple[list[DemoJob], list[ThrowJob]]:
    """
    Return the study's jobs: stage 1 the demonstrations, stage 2 the throws.

    Parameters
    ----------
    config : dict
        Output of :func:`build_config`.

    Returns
    -------
    demos : list of DemoJob
    throws : list of ThrowJob
        Jobs for :func:`suture_lfd.study.jobs.run_job`, each with its ``id``
        (:func:`suture_lfd.study.keys.with_ids`).

    """
    seed = config['seed']
    order = [(ph, p) for ph, pairs in config['phantoms'].items() for p in pairs]
    rank = {p: k for k, (_, p) in enumerate(order)}
    demos, throws = [], []
    for subject in config['subjects']:
        name = subject['name']
        for ph, pairs in config['phantoms'].items():
            for k, pair in enumerate(pairs):
                key = f'demo/{name}/{pair}'
                demos.append(DemoJob(
                    key=key, subject=name, group=subject['group'],
                    phantom=ph, pair=pair, order=rank[pair],
                    next_pair=pairs[k + 1] if k + 1 < len(pairs) else None,
                    seed=job_seed(seed, key), bag=f'bags/{name}_{pair}',
                    segments=f'segments/{name}_{pair}.npz'))
    for method in config['methods']:
        for subject in config['subjects']:
            name = subject['name']
            for train_ph, train in order:
                for test_ph, test in order:
                    key = f'throw/{method}/{name}/{train}/{test}'
                    throws.append(ThrowJob(
                        key=key, subject=name,
                        group=subject['group'], method=method, train_phantom=train_ph,
                        train_pair=train, train_order=rank[train], test_phantom=test_ph,
                        test_pair=test, test_order=rank[test],
                        seed=job_seed(seed, key),
                        demo_key=f'demo/{name}/{train}',
                        trajectories=(f'trajectories/{method}_{name}_{train}.npz'
                                      if train == test else None)))
    demos = with_ids(demos, config)
    return demos, with_ids(throws, config, demo_ids(demos))


def attach_demos(throws: Sequence[ThrowJob], store: ResultStore, demos: Sequence[DemoJob]
                 ) -> list[ThrowJob]:
    """
    Fill each throw job with its training demonstration's segment file and time.

    A throw whose demonstration job raised an error (or is missing) gets ``blocked``: it is
    stored as an error too, so that a later run does it again once the demonstration exists.

    Parameters
    ----------
    throws : list of ThrowJob
        Throw jobs with their ``id`` (:func:`plan_jobs`).
    store : suture_lfd.study.store.ResultStore
        The stored records, where the demonstrations are found.
    demos : list of DemoJob
        The demonstration jobs the throws name by ``demo_key``.

    Returns
    -------
    list of ThrowJob
        The throws with ``segments``, ``demo_time_s`` or ``blocked``.

    """
    by_key = {job.key: job.id for job in demos}
    out = []
    for job in throws:
        demo = store.records.get(by_key.get(job.demo_key, ''))
        if demo is None or demo.error:
            out.append(dataclasses.replace(
                job, segments=None, demo_time_s=None,
                blocked=f'demonstration {job.demo_key} '
                        + ('failed: ' + demo.error if demo else 'missing')))
            continue
        out.append(dataclasses.replace(job, segments=demo.segments if demo.ok else None,
                                       demo_time_s=demo.time_s))
    return out


def ordered_records(store: ResultStore, jobs: Sequence[DemoJob | ThrowJob]) -> list[Record]:
    """
    Return the stored records of ``jobs``, in the jobs' order, placed as in this run.

    A record stored by another run in the folder (another method order, more pairs) keeps its
    results; its bookkeeping fields (its place in the report's order, its demonstration's name)
    are this run's.
    """
    out = []
    for job in jobs:
        record = store.records.get(job.id)
        if record is not None:
            shared = ({f.name for f in dataclasses.fields(record)}
                      & {f.name for f in dataclasses.fields(job)})
            out.append(dataclasses.replace(record, **{k: getattr(job, k) for k in BOOKKEEPING
                                                      if k in shared}))
    return out


# ---------------------------------------------------------------------- main
def run_study(args: argparse.Namespace, stream: IO[str] | None = None) -> int:
    """
    Run (or resume) the study of the options and write its report.

    Every job whose result is stored in the folder (by its ``id``) is reused; the others run on
    the chosen engine. SIGINT or SIGTERM stop the run (:mod:`suture_lfd.study.signals`): the
    results stored so far stay, no report is written, and the exit status says which signal.

    Parameters
    ----------
    args : argparse.Namespace
        Options of :func:`suture_lfd.study.options.add_study_arguments`.
    stream : file-like, optional
        Progress output (default ``sys.stderr``).

    Returns
    -------
    int
        Exit status: 0 done, 1 the engine failed, 2 bad options, 130 / 143 interrupted by
        SIGINT / SIGTERM (rerun to resume).

    """
    stream = stream if stream is not None else sys.stderr
    t0 = time.monotonic()
    ros = None
    try:
        config = build_config(args)
        engine = parse_engine(getattr(args, 'engine', 'local'))
        if args.via_ros and not (args.plan or args.report_only):
            from suture_lfd.study.ros import check_executables, study_settings

            check_executables()
            ros = study_settings()
    except (ValueError, OSError) as exc:
        print(f'suture-lfd study: error: {exc}', file=sys.stderr)
        return 2
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    digest = config_hash(hashed_config(config))
    config['hash'] = digest
    demos, throws = plan_jobs(config)
    held_jobs = with_ids(held_out.plan_held_out(config, job_seed), config, demo_ids(demos))
    phys_demos: list[DemoJob] = []
    phys_throws: list[ThrowJob] = []
    if config.get('physical'):
        phys_demos, phys_throws = physical.plan_physical(config['physical'], demos, throws,
                                                         job_seed, config['seed'])
        phys_demos = with_ids(phys_demos, config)
        phys_throws = with_ids(phys_throws, config, demo_ids(demos + phys_demos))
    (out / 'config.json').write_text(json.dumps(config, indent=1, sort_keys=True) + '\n')
    jobs: list[DemoJob | ThrowJob] = [*demos, *throws, *held_jobs, *phys_demos, *phys_throws]
    total = len(jobs)
    print(f'study {digest}: {len(config["subjects"])} subjects, '
          f'{sum(len(p) for p in config["phantoms"].values())} pairs, methods '
          f'{", ".join(config["methods"])}: {len(demos)} demonstrations + {len(throws)} '
          f'throws' + (f' + {len(held_jobs)} held-out throws' if held_jobs else '')
          + (f'; physical mode ({len(physical.variants(config["physical"]))} variants): '
             f'{len(phys_demos)} demonstrations + {len(phys_throws)} throws'
             if phys_throws else '')
          + f'; results in {out}', file=stream, flush=True)
    if args.plan:
        (out / 'jobs.json').write_text(json.dumps([plan_json(job) for job in jobs], indent=1)
                                       + '\n')
        return 0
    if args.workers is not None:
        workers = args.workers
    elif args.via_ros:  # a throw keeps two node processes busy
        workers = max(1, (os.cpu_count() or 1) // 2)
    else:
        workers = os.cpu_count() or 1
    if workers < 1:
        print(f'suture-lfd study: error: --workers must be >= 1, got {workers}', file=sys.stderr)
        return 2
    settings = JobSettings(out=str(out), cohort_path=config['cohort_file'],
                           cohort_seed=config['seed'],
                           tissue=config['settings'].get('tissue', 'none'),
                           camera=config['settings'].get('camera', 'none'))
    status = 0
    with stop_on_signals('study') as stop, ResultStore(out) as store:
        reused = stored_note('study', store, jobs, stream)
        progress = Progress(total, done=reused, stream=stream)
        if not args.report_only:
            stages = [Stage(lambda: demos + phys_demos, (settings,))]
            if held_jobs:  # fewer than the matrix's throws: their figure comes first
                stages.append(Stage(lambda: attach_demos(held_jobs, store, demos), (settings,)))
            stages.append(Stage(lambda: attach_demos(throws, store, demos), (settings, ros)))
            if phys_throws:  # in-process, whatever --via-ros says
                stages.append(Stage(lambda: attach_demos(phys_throws, store, demos + phys_demos),
                                    (settings,)))
            status = run_job_stages('study', engine, stages, jobs, store, stop, progress,
                                    workers, stream)
            if status > 128:
                return status
        ran = progress.done - progress.resumed
        wall = time.monotonic() - t0
        records = ordered_records(store, [*demos, *throws])
        held_records = [r for r in ordered_records(store, held_jobs) if isinstance(r, ThrowRecord)]
        phys_records = ordered_records(store, [*phys_demos, *phys_throws])
    command = 'suture-lfd study ' + ' '.join(shlex.quote(a) for a in _study_argv())
    run_info = {'command': command.strip(), 'workers': workers, 'engine': engine.describe(),
                'jobs_run': ran, 'resumed': reused, 'results_file': store.path.name,
                'wall_s': wall, 'rate': ran / wall if wall > 0 else 0.0}
    from suture_lfd.study import report as report_writer  # matplotlib: only when writing

    path = report_writer.write_report(out, records, config, run_info)
    if held_jobs:
        _write_held_out(out, path, records, held_records, config)
    if config.get('physical'):
        _write_physical(out, path, records, phys_records, config, run_info)
    stored = len(records) + len(held_records) + len(phys_records)
    missing = total - stored
    print(f'report: {path} ({stored}/{total} jobs'
          + (f', {missing} missing' if missing else '') + f'; {ran} run, {reused} reused; '
          f'{wall:.1f} s)', file=stream, flush=True)
    return status


def stored_note(what: str, store: ResultStore, jobs: Sequence[DemoJob | ThrowJob],
                stream: IO[str]) -> int:
    """
    Say what the folder already holds for a run's jobs; return how many of them are reused.

    Prints, when there is anything to say: how many jobs are reused from the results file,
    how many stored records belong to no job of this run (other methods, design, seed,
    configuration files or code: kept, never mixed in), and the result files of the earlier
    format, which are not read.
    """
    ids = {job.id for job in jobs}
    reused = sum(1 for job in jobs if store.done(job) is not None)
    other = sum(1 for job_id in store.records if job_id not in ids)
    if reused:
        print(f'{what}: {reused} of {len(jobs)} jobs reused from {store.path.name} (stored with '
              'the same inputs and code)', file=stream, flush=True)
    if other:
        print(f'{what}: {other} stored results in {store.path.name} are of other jobs (other '
              'methods, design, seed, configuration files or code): kept, not used',
              file=stream, flush=True)
    for path in earlier_format_files(store.folder):
        print(f'{what}: {path.name} holds results of an earlier format, keyed by the whole '
              "configuration rather than by each job's inputs: not read, its jobs run again "
              '(delete it once it is no longer needed)', file=stream, flush=True)
    return reused


def _write_held_out(out: Path, report: Path, records: Sequence[Record],
                    held_records: Sequence[ThrowRecord], config: dict[str, Any]) -> None:
    """Add the held-out geometry section to the report, and ``held_out.csv``."""
    from suture_lfd.study.report import write_csv

    ok = [r for r in held_records if not r.error]
    write_csv(out / 'held_out.csv', held_out.held_out_rows(ok, config), held_out.HELD_OUT_COLUMNS)
    (out / 'held_out.json').write_text(
        json.dumps(held_out.summarise(records, ok), indent=1, sort_keys=True) + '\n')
    with open(report, 'a') as f:
        f.write('\n' + '\n'.join(held_out.report_section(records, ok, config)) + '\n')


def _write_physical(out: Path, report: Path, ground_records: Sequence[Record],
                    records: Sequence[Record], config: dict[str, Any],
                    run_info: dict[str, Any]) -> None:
    """Write a report per physical-mode variant and the main report's physical section."""
    from suture_lfd.study.report import summarise, write_csv, write_report

    ground_truth = summarise(ground_records)
    variant_config = {**config, 'assessment': 'off'}
    summaries = {}
    for v in physical.variants(config['physical']):
        folder = out / 'physical' / v.name
        folder.mkdir(parents=True, exist_ok=True)
        ground_demos = ([r for r in ground_records if isinstance(r, DemoRecord)]
                        if config['physical'].get('demos') == 'ground-truth' else None)
        mine = physical.variant_records(records, v.name, v.level, ground_demos)
        write_report(folder, mine, variant_config, run_info)
        summaries[v] = summarise(mine)
    curve = None
    if physical.has_curve(config['physical']):
        rows = physical.curve_rows(summaries, ground_truth)
        write_csv(out / 'physical_curve.csv', rows, physical.CURVE_COLUMNS)
        curve = physical.curve_figure(rows, out / 'physical_curve.png').name
    if config['physical'].get('ablation'):
        write_csv(out / 'physical_ablation.csv', physical.ablation_rows(summaries, ground_truth),
                  physical.ABLATION_COLUMNS)
    lines = physical.report_section(summaries, ground_truth, config['physical'], curve)
    with open(report, 'a') as f:
        f.write('\n' + '\n'.join(lines) + '\n')


def _study_argv() -> list[str]:
    argv = sys.argv[1:]
    return argv[argv.index('study') + 1:] if 'study' in argv else argv


def main(args: argparse.Namespace) -> int:
    """Entry point of ``suture-lfd study`` (called by :mod:`suture_lfd.cli`)."""
    return run_study(args)
