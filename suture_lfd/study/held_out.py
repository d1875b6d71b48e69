"""
Held-out geometry for ``suture-lfd study``: skills executed on pairs they were never designed on.

The study's generality matrix uses the eight fixed marker pairs the methods were developed on.
``--held-out N`` adds, for every phantom of the design, ``N`` random entry/exit pairs drawn on
its wound line (seeded by ``--held-out-seed``): the pair's centre at an arc length drawn
uniformly between the phantom's first and last fixed pair (the markers' spacing range), entry
and exit ``half_width`` either side of the line as the fixed pairs. ``--held-out-mesh FILE``
adds the same number of random pairs on a user mesh (a mesh file, or a phantom file with its
wound line; :func:`sim_bridge.scene.scene_config.load_phantom_file`).

Every subject executes every held-out pair once per method, with its skill learnt on one of its
fixed pairs, taken in turn (the ``k``-th held-out pair of subject ``j`` uses fixed pair
``(k + j) mod n``), so every fixed pair teaches about as often and the held-out throws cost
``subjects x pairs`` per method. The held-out throws are ``held_out`` records, never part of the
fixed-pair tables; the report gets a "held-out geometry" section with generality (mean score) on
them beside the fixed-pair figure, and ``held_out.csv`` lists them.

Frames: held-out pairs are stored in the mesh file's frame (metres, after the mesh scale); for
the generated pads that is the phantom frame.
"""

import argparse
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict
import hashlib
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any
import zlib

import numpy as np
from suture_lfd.study.records import Record, ThrowJob, ThrowRecord

if TYPE_CHECKING:
    from sim_bridge.scene.phantom import Phantom, PhantomConfig

HELD_OUT_COLUMNS = (
    'subject', 'group', 'method', 'train_phantom', 'train_pair', 'test_phantom', 'test_pair',
    'entry_x_mm', 'entry_y_mm', 'exit_x_mm', 'exit_y_mm', 'seed', 'score', 'i', 'ii', 'iii',
    'iv', 'v', 'failure', 'time_s', 'entry_error_mm', 'exit_error_mm')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the held-out geometry options to the study's argparse parser."""
    parser.add_argument('--held-out', type=int, default=0, metavar='N',
                        help='also execute every skill on N random pairs per phantom drawn on '
                             "its wound line within the markers' spacing range, and report "
                             'generality on them beside the fixed pairs (default 0: off)')
    parser.add_argument('--held-out-seed', type=int, default=None,
                        help='seed of the random pairs (default: the study seed)')
    parser.add_argument('--held-out-mesh', default=None, metavar='FILE',
                        help='a user mesh (STL/OBJ/PLY, metres) or phantom file (.yaml, with '
                             'its wound line) that also gets N random pairs (needs --held-out)')


def _digest(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


def random_pairs(phantom: 'Phantom', count: int, seed: int) -> dict[str, dict[str, Any]]:
    """
    Draw random entry/exit pairs on a phantom's wound line within its markers' spacing range.

    Parameters
    ----------
    phantom : sim_bridge.scene.phantom.Phantom
        A built phantom with a wound line.
    count : int
        Number of pairs.
    seed : int
        Seed; with the phantom's name it fixes the pairs (the first ``k`` of ``count`` pairs
        are those of ``k``).

    Returns
    -------
    dict
        Pair name (``<prefix>r1`` ..) -> ``{'entry': [x, y], 'exit': [x, y]}`` in the mesh
        file's frame (m).

    """
    from sim_bridge.scene.mesh_placement import apply_xy

    w = phantom.config.wound
    wound = phantom.wound
    if wound is None:
        raise ValueError(f'phantom {phantom.name} has no wound line to draw held-out pairs on')
    centre = 0.5 * wound.length + w.offset
    half_span = 0.5 * (max(w.n_pairs, 1) - 1) * w.spacing
    rng = np.random.default_rng([int(seed), zlib.crc32(phantom.name.encode())])
    s = rng.uniform(centre - half_span, centre + half_span, count)
    T_file_phantom = np.linalg.inv(phantom.T_phantom_file)
    pairs: dict[str, dict[str, Any]] = {}
    for k, sk in enumerate(s, start=1):
        c = wound.point(sk)
        left = wound.left(sk) * w.half_width * w.entry_side
        entry, exit_ = apply_xy(T_file_phantom, np.array([c + left, c - left]))
        pairs[f'{phantom.config.marker_prefix}r{k}'] = {
            'entry': [float(v) for v in entry], 'exit': [float(v) for v in exit_]}
    return pairs


def _phantom_spec(config: 'PhantomConfig', pairs: dict[str, dict[str, Any]],
                  phantom: 'Phantom') -> dict[str, Any]:
    """Return the JSON-serialisable phantom configuration of a held-out simulation."""
    import dataclasses

    from sim_bridge.scene.mesh_placement import apply_xy

    d = dataclasses.asdict(config)
    if config.kind == 'mesh' and config.frame == 'wound':
        # keep the phantom frame the placement gave: its wound line, in file coordinates
        line = apply_xy(np.linalg.inv(phantom.T_phantom_file), phantom.config.wound.line)
        d['wound']['line'] = [[float(x), float(y)] for x, y in line]
    d['markers'] = pairs
    return d


def held_out_config(args: argparse.Namespace, phantoms: dict[str, Any], seed: int
                    ) -> dict[str, Any] | None:
    """
    Return the held-out part of the study's configuration (None when off).

    Parameters
    ----------
    args : argparse.Namespace
        Study options (``held_out``, ``held_out_seed``, ``held_out_mesh``).
    phantoms : dict
        The design's phantoms (name -> fixed pairs).
    seed : int
        Study seed (the default held-out seed).

    Returns
    -------
    dict or None
        ``seed``, ``count``, ``phantoms`` (name -> ``config`` (phantom configuration with the
        held-out markers), ``pairs`` (names), ``key`` (what identifies the geometry)).

    Raises
    ------
    ValueError
        Bad count, unreadable mesh or phantom file, or a phantom without a wound line.

    """
    count = getattr(args, 'held_out', 0) or 0
    mesh = getattr(args, 'held_out_mesh', None)
    if count < 0:
        raise ValueError(f'--held-out must be >= 0, got {count}')
    if not count:
        if mesh:
            raise ValueError('--held-out-mesh needs --held-out N (random pairs per phantom)')
        return None
    if getattr(args, 'via_ros', False):
        raise ValueError('--held-out runs its throws in-process; leave out --via-ros')
    from sim_bridge.scene.phantom import build_phantom
    from sim_bridge.scene.scene_config import load_scene_config, phantom_from_argument

    hseed = seed if getattr(args, 'held_out_seed', None) is None else args.held_out_seed
    if hseed < 0:
        raise ValueError(f'--held-out-seed must be >= 0, got {hseed}')
    scene = load_scene_config()
    out: dict[str, Any] = {}
    sources: list[tuple[str, Any, str | None]] = [
        (name, scene.phantom_config(name), None) for name in phantoms]
    if mesh:
        path = Path(mesh).resolve()
        name, config = phantom_from_argument(scene, path)
        mesh_digest = _digest(path) + (_digest(str(config.mesh))
                                       if path.suffix.lower() in ('.yaml', '.yml') else '')
        sources.append((name, config, mesh_digest))
    for name, config, digest in sources:
        if name in out:
            raise ValueError(f'--held-out-mesh {mesh}: its name {name!r} is a phantom of the '
                             f'design; rename the file')
        phantom = build_phantom(config, name=name)
        pairs = random_pairs(phantom, count, hseed)
        out[name] = {'config': _phantom_spec(config, pairs, phantom), 'pairs': list(pairs),
                     'key': f'{name}@{hseed}' + (f'/{digest}' if digest else ''),
                     'mesh': str(config.mesh) if config.mesh else None,
                     'placement': phantom.placement}
    return {'seed': int(hseed), 'count': int(count), 'phantoms': out}


def plan_held_out(config: dict[str, Any], job_seed: Callable[[int, str], int]
                  ) -> list[ThrowJob]:
    """
    Return the held-out throw jobs of a study configuration.

    Parameters
    ----------
    config : dict
        The study configuration with its ``held_out`` part.
    job_seed : callable
        ``job_seed(study_seed, key)``: the scene seed of a job.

    Returns
    -------
    list of ThrowJob
        Jobs of kind ``held_out`` (run like throws; records kept apart).

    """
    held = config.get('held_out')
    if not held:
        return []
    order = [(ph, p) for ph, pairs in config['phantoms'].items() for p in pairs]
    jobs = []
    for method in config['methods']:
        for j, subject in enumerate(config['subjects']):
            name = subject['name']
            k = 0
            for phantom, spec in held['phantoms'].items():
                for pair in spec['pairs']:
                    train_ph, train = order[(k + j) % len(order)]
                    k += 1
                    key = f'held_out/{method}/{name}/{train}/{spec["key"]}/{pair}'
                    jobs.append(ThrowJob(
                        key=key, kind='held_out', subject=name,
                        group=subject['group'], method=method,
                        train_phantom=train_ph, train_pair=train,
                        test_phantom=phantom, test_pair=pair,
                        test_key=spec['key'], test_config=spec['config'],
                        seed=job_seed(config['seed'], key),
                        demo_key=f'demo/{name}/{train}', trajectories=None))
    return jobs


def phantom_config(spec: Mapping[str, Any]) -> 'PhantomConfig':
    """Rebuild a held-out simulation's PhantomConfig from its JSON-serialisable form."""
    from sim_bridge.common.configfile import dataclass_from_mapping
    from sim_bridge.scene.phantom import PhantomConfig

    return dataclass_from_mapping(PhantomConfig, spec, source='held-out phantom')


def _mean(values: Iterable[float | None]) -> float:
    kept = [v for v in values if v is not None and not math.isnan(v)]
    return float(np.mean(kept)) if kept else float('nan')


def _f(x: float | None, digits: int = 3) -> str:
    return '–' if x is None or (isinstance(x, float) and math.isnan(x)) else f'{x:.{digits}f}'


def summarise(records: Sequence[Record], held_records: Sequence[ThrowRecord]
              ) -> dict[str, dict[str, Any]]:
    """
    Generality on the fixed and on the held-out pairs, per method, group and phantom.

    Parameters
    ----------
    records : list of DemoRecord or ThrowRecord
        The study's records (``throw`` ones give the fixed-pair figure).
    held_records : list of ThrowRecord
        The ``held_out`` records.

    Returns
    -------
    dict
        method -> ``{'fixed': {group: mean}, 'held_out': {group: mean}, 'n_fixed': int,
        'n_held_out': int, 'phantoms': {phantom: {group: mean, 'n': int}}}``.

    """
    out: dict[str, dict[str, Any]] = {}
    methods: list[str] = []
    for r in held_records:
        if r.method not in methods:
            methods.append(r.method)
    for method in methods:
        fixed = [r for r in records if isinstance(r, ThrowRecord) and r.kind == 'throw'
                 and not r.error and r.method == method]
        held = [r for r in held_records if r.method == method and not r.error]
        entry: dict[str, Any] = {'n_fixed': len(fixed), 'n_held_out': len(held), 'fixed': {},
                                 'held_out': {}, 'phantoms': {}}
        for label, rows in (('fixed', fixed), ('held_out', held)):
            for group in ('experienced', 'naive'):
                entry[label][group] = _mean([r.score for r in rows if r.group == group])
            entry[label]['overall'] = _mean([r.score for r in rows])
        for phantom in dict.fromkeys(r.test_phantom for r in held):
            rows = [r for r in held if r.test_phantom == phantom]
            ph: dict[str, Any] = {g: _mean([r.score for r in rows if r.group == g])
                  for g in ('experienced', 'naive')}
            ph['overall'] = _mean([r.score for r in rows])
            ph['n'] = len(rows)
            ph['complete'] = sum(1 for r in rows if r.score == 1.0)
            entry['phantoms'][phantom] = ph
        out[method] = entry
    return out


def report_section(records: Sequence[Record], held_records: Sequence[ThrowRecord],
                   config: dict[str, Any]) -> list[str]:
    """
    Markdown section of the report: generality on held-out pairs beside the fixed pairs.

    Parameters
    ----------
    records : list of DemoRecord or ThrowRecord
        The study's records.
    held_records : list of ThrowRecord
        The ``held_out`` records.
    config : dict
        The study configuration (its ``held_out`` part).

    Returns
    -------
    list of str
        Markdown lines.

    """
    held = config['held_out']
    summary = summarise(records, held_records)
    md = ['## Held-out geometry', '',
          f"Every subject's skills executed on pairs that are not among the fixed ones: "
          f"{held['count']} random pairs per phantom (seed {held['seed']}) drawn on its wound "
          "line, each pair's centre uniform between the first and last fixed pair along the "
          'line, entry and exit as far from the line as the fixed pairs. Each held-out pair '
          "is executed once per subject and method, with the subject's skill learnt on one "
          'fixed pair taken in turn. Generality = mean score (as in Table III). Throws: '
          '`held_out.csv`.', '']
    for name, spec in held['phantoms'].items():
        if spec.get('mesh'):
            md += [f'User mesh `{name}`: `{Path(spec["mesh"]).name}`'
                   + (f' ({spec["placement"]})' if spec.get('placement') else '') + '.', '']
    md += ['| method | pairs | experienced | naive | overall | throws |',
           '|---|---|---|---|---|---|']
    for method, s in summary.items():
        for label, text in (('fixed', 'fixed (Table III)'), ('held_out', 'held-out, all')):
            g = s[label]
            md.append(f'| `{method}` | {text} | {_f(g["experienced"])} | {_f(g["naive"])} | '
                      f'**{_f(g["overall"])}** | {s["n_" + label]} |')
        for phantom, g in s['phantoms'].items():
            md.append(f'| `{method}` | held-out, {phantom} | {_f(g["experienced"])} | '
                      f'{_f(g["naive"])} | {_f(g["overall"])} | {g["n"]} '
                      f'({g["complete"]} complete) |')
    md.append('')
    return md


def held_out_rows(held_records: Iterable[ThrowRecord], config: dict[str, Any]
                  ) -> list[dict[str, Any]]:
    """Return the held-out records as CSV rows, with the pairs' marker positions (file, mm)."""
    specs = config['held_out']['phantoms']
    rows = []
    for r in sorted(held_records, key=lambda r: (r.method, r.subject, r.test_phantom,
                                                r.test_pair)):
        if r.error:
            continue
        spec = specs.get(r.test_phantom, {}).get('config', {})
        pair = (spec.get('markers') or {}).get(r.test_pair)
        row = asdict(r)
        if pair:
            row.update(entry_x_mm=1e3 * pair['entry'][0], entry_y_mm=1e3 * pair['entry'][1],
                       exit_x_mm=1e3 * pair['exit'][0], exit_y_mm=1e3 * pair['exit'][1])
        rows.append(row)
    return rows
