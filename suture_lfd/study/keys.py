"""
A job's ``id``: the digest of what decides its result, and nothing else.

A study's jobs are found in its folder's :class:`~suture_lfd.study.store.ResultStore` by ``id``,
so a study, a sweep cell, a held-out run or the same study with its methods reordered or one
added reuses every job it shares with what is stored, and a record computed from other inputs
is never taken for one of its jobs. The ``id`` is the SHA-256 (first 16 hex digits) of the
canonical JSON of

- the job's own fields but the bookkeeping ones (:data:`BOOKKEEPING`: its place in the report's
  order, the name of the demonstration it learns from): kind, method, pairs learnt on and
  executed on (and a held-out pair's phantom configuration), scene seed, a sweep cell's DMP
  values, where its files go, its name (the key);
- its subject as the configuration gives it (name, group, seed, skill profile);
- for a throw, the ``id`` of the demonstration it learns from (so everything that decided the
  demonstration decides the throw too);
- the study's context (:func:`job_context`): the job settings (cohort seed, steps, rates,
  timeouts), the digests of the configuration files (scene, world, DMP, kinematics, cohort),
  the code digest (:func:`suture_lfd.study.digest.code_digest`), the ``--via-ros`` node
  settings, and :data:`ID_FORMAT`.

Which other methods, subjects or pairs run beside a job, and in which order, is not in it.
"""

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any, TypeVar

from suture_lfd.study.records import DemoJob, ThrowJob, to_json
from suture_lfd.study.store import config_hash

J = TypeVar('J', DemoJob, ThrowJob)

#: Version of the recipe: a change of what goes into an ``id`` changes every ``id``.
ID_FORMAT = 1
#: Job fields that say where a job stands in a run, not what it computes.
BOOKKEEPING = ('id', 'order', 'train_order', 'test_order', 'demo_key')


def job_context(config: Mapping[str, Any]) -> dict[str, Any]:
    """
    Return what every job of a study configuration depends on beside its own fields.

    Parameters
    ----------
    config : dict
        A study configuration (:func:`suture_lfd.study.run.build_config`).

    Returns
    -------
    dict
        ``format``, ``settings``, ``files``, ``code`` and ``via_ros``.

    """
    return {'format': ID_FORMAT, 'settings': config['settings'], 'files': config['files'],
            'code': config['code'], 'via_ros': config.get('via_ros')}


def with_ids(jobs: Sequence[J], config: Mapping[str, Any],
             demo_ids: Mapping[str, str] | None = None) -> list[J]:
    """
    Return the jobs with their ``id``, demonstrations first in the list or in ``demo_ids``.

    Parameters
    ----------
    jobs : list of DemoJob or ThrowJob
        Jobs of one study configuration; a throw names its demonstration by ``demo_key``.
    config : dict
        That configuration (its subjects and context).
    demo_ids : dict, optional
        ``demo key -> id`` of demonstrations planned elsewhere (held-out throws learn from the
        study's demonstrations).

    Returns
    -------
    list of DemoJob or ThrowJob
        Copies of the jobs with ``id`` set.

    Raises
    ------
    KeyError
        A throw whose demonstration has no ``id`` yet.

    """
    context = job_context(config)
    subjects = {s['name']: s for s in config['subjects']}
    ids = dict(demo_ids or {})
    out: list[J] = []
    for job in jobs:
        decided = {k: v for k, v in to_json(job).items()
                   if k not in BOOKKEEPING and v is not None}
        decided['subject'] = subjects[job.subject]
        if isinstance(job, ThrowJob):
            decided['demo'] = ids[job.demo_key]
        digest = config_hash({'job': decided, 'context': context}, length=16)
        out.append(replace(job, id=digest))
        if isinstance(job, DemoJob):
            ids[job.key] = digest
    return out


def demo_ids(demos: Sequence[DemoJob]) -> dict[str, str]:
    """Return ``demo key -> id`` of demonstration jobs that have their ``id``."""
    return {job.key: job.id for job in demos}
