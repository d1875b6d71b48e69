"""
Skill assessment of demonstrations: objective scores from the suturing-skill literature.

:mod:`~suture_lfd.assessment.motion` measures one instrument's motion;
:mod:`~suture_lfd.assessment.demo_scores` scores one demonstration from its record and segment
file; :mod:`~suture_lfd.assessment.acceptance` combines the scores into the rule that decides
which demonstrations a skill is learnt from.
"""
