"""
Which demonstrations a skill may be learnt from: expert-derived proficiency bounds.

The rule follows proficiency-based suturing curricula, whose pass marks are set from experts'
performance (the experts' mean plus a margin of their spread) rather than fitted to outcomes:
a demonstration is **accepted** when each screened score lies within ``mean + k_sd * SD`` of the
reference group's demonstrations (the experienced subjects), computed without the assessed
subject's own demonstrations (leave one subject out), so no demonstration is judged against
itself. Nothing here sees a throw executed with a learnt skill.

The screened scores are those of the needle path the skill copies (subtasks ii and iv are
learnt from the needle trajectory, the rest is planned): entry and exit accuracy, the tilt of
the needle plane during the insertion, and how far the needle strays from its arc inside the
tissue. Time, economy, smoothness and idle time describe the operator more than the path a
DMP reproduces (a slower or shakier hand on the same path teaches the same skill), so they are
reported but not screened by default.

The combined score of a demonstration is the largest of its screened z-scores,
``z_m = (value_m - mean_m) / SD_m`` (larger = worse; accepted when ``<= k_sd``), and the
reasons of a rejection name each score over its bound.
"""

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
import math
from typing import Any

import numpy as np

SCREENED = ('entry_error_mm', 'exit_error_mm', 'tilt_mean_deg', 'arc_deviation_max_mm')


@dataclass(frozen=True)
class AcceptanceRule:
    """
    Expert-derived proficiency bounds.

    Attributes
    ----------
    metrics : tuple of str
        Screened scores (columns of :func:`suture_lfd.assessment.demo_scores.assess_demonstration`;
        larger = worse).
    reference_group : str
        Group whose demonstrations set the bounds.
    k_sd : float
        Margin in standard deviations of the reference group.

    """

    metrics: tuple = SCREENED
    reference_group: str = 'experienced'
    k_sd: float = 2.0

    def __post_init__(self) -> None:
        if not self.metrics:
            raise ValueError('AcceptanceRule.metrics must name at least one score')
        if not (isinstance(self.k_sd, (int, float)) and math.isfinite(self.k_sd)
                and self.k_sd > 0.0):
            raise ValueError(f'AcceptanceRule.k_sd must be a number > 0, got {self.k_sd!r}')


def proficiency_bounds(rows: Sequence[Mapping[str, Any]], rule: 'AcceptanceRule',
                       without_subject: str | None = None
                       ) -> dict[str, tuple[float, float, float]]:
    """
    Return ``metric -> (mean, sd, bound)`` of the reference group's demonstrations.

    Parameters
    ----------
    rows : list of dict
        Scored demonstrations with ``subject`` and ``group``.
    rule : AcceptanceRule
    without_subject : str, optional
        Subject left out of the reference.

    Raises
    ------
    ValueError
        If fewer than two reference demonstrations remain.

    """
    ref = [r for r in rows
           if r.get('group') == rule.reference_group and r.get('subject') != without_subject]
    if len(ref) < 2:
        raise ValueError(f'proficiency bounds need at least two demonstrations of the '
                         f'{rule.reference_group!r} group besides {without_subject!r}, got '
                         f'{len(ref)}')
    out: dict[str, tuple[float, float, float]] = {}
    for metric in rule.metrics:
        values = np.array([float(r[metric]) for r in ref], float)
        values = values[np.isfinite(values)]
        if values.size < 2:
            raise ValueError(f'proficiency bounds: fewer than two finite {metric!r} scores in '
                             f'the {rule.reference_group!r} group')
        mean, sd = float(values.mean()), float(values.std(ddof=1))
        out[metric] = (mean, sd, mean + rule.k_sd * sd)
    return out


def assess_cohort(rows: Sequence[Mapping[str, Any]], rule: 'AcceptanceRule | None' = None
                  ) -> list[dict[str, Any]]:
    """
    Return each demonstration's combined score, verdict and reasons.

    Parameters
    ----------
    rows : list of dict
        Scored demonstrations (:func:`~suture_lfd.assessment.demo_scores.assess_demonstration`
        rows with ``subject`` and ``group``).
    rule : AcceptanceRule, optional

    Returns
    -------
    list of dict
        Per row, in order: ``combined_score`` (largest z-score), ``accepted`` (bool) and
        ``reasons`` (``'tilt_mean_deg 7.02 > 3.43; ...'``, empty when accepted). A score that
        is not finite (the tip never crossed the surface) rejects the demonstration.

    """
    rule = AcceptanceRule() if rule is None else rule
    cache = {}
    out = []
    for r in rows:
        subject = r.get('subject')
        if subject not in cache:
            cache[subject] = proficiency_bounds(rows, rule, without_subject=subject)
        bounds = cache[subject]
        z_max, reasons = -math.inf, []
        for metric in rule.metrics:
            mean, sd, bound = bounds[metric]
            value = float(r[metric])
            if not math.isfinite(value):
                z_max = math.inf
                reasons.append(f'{metric} not measured')
                continue
            z = (value - mean) / sd if sd > 0.0 else (0.0 if value <= mean else math.inf)
            z_max = max(z_max, z)
            if value > bound:
                reasons.append(f'{metric} {value:.2f} > {bound:.2f}')
        out.append({'combined_score': z_max, 'accepted': not reasons,
                    'reasons': '; '.join(reasons)})
    return out
