"""
``suture-lfd study``: the seed paper's user study and evaluation, in simulation, with its report.

The default design is the paper's (Zhou et al., ISMR 2024, Sec. III-C and IV): the cohort of
``config/cohort.yaml`` (10 synthetic subjects, 4 experienced and 6 naive) each demonstrates a
throw on the four marker pairs of each phantom, in order; every demonstration is recorded as a
bag, read back and segmented by the segmenter's code; then, for every method (``paper`` and the
others of :data:`suture_lfd.skill.METHODS`), every subject's skill learnt on each pair is
executed on every pair (the generality matrix, 64 throws per subject; its diagonal is the
regeneration test of Table II). The report folder (``--out``) gets ``report.md`` with the
paper's tables beside ours, PNG figures, ``throws.csv`` / ``demos.csv`` and the configuration.

The modules:

- :mod:`~suture_lfd.study.options`: the command-line options (light: every ``suture-lfd``
  command builds its parser from them; the rest is imported when a study or sweep runs);
- :mod:`~suture_lfd.study.run`: the configuration, the jobs and :func:`~suture_lfd.study.run.
  run_study`; :mod:`~suture_lfd.study.physical`: the study in physical mode;
- :mod:`~suture_lfd.study.jobs`: what a job does (a demonstration, a throw);
- :mod:`~suture_lfd.study.keys`: a job's ``id``, the digest of what decides its result, by which
  :mod:`~suture_lfd.study.store` finds it again (resume, reuse across runs in a folder);
- :mod:`~suture_lfd.study.runner`, :mod:`~suture_lfd.study.pool`,
  :mod:`~suture_lfd.study.engine`: where jobs run (in-process, local processes, Dask);
- :mod:`~suture_lfd.study.signals`: SIGINT and SIGTERM stop a run the same way everywhere;
- :mod:`~suture_lfd.study.report` (with ``tables``, ``figures``, ``assessed``,
  ``held_out``): the report; :mod:`~suture_lfd.study.sweep`: grids of studies;
  :mod:`~suture_lfd.study.ros`: throws through the node graph (``--via-ros``).
"""

from suture_lfd.study.digest import code_digest
from suture_lfd.study.options import add_study_arguments, add_sweep_arguments

__all__ = ['add_study_arguments', 'add_sweep_arguments', 'code_digest']
