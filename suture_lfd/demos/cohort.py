"""
Synthetic study subjects: skill profiles of experienced and naive demonstrators.

The seed paper's user study (Sec. III-C-2): 10 subjects, 4 with previous surgical training and
dVRK experience ("experienced"), 6 without ("naive"); each sutures the four marker pairs of each
phantom in order (``synth1`` .. ``synth4``, then ``scan1`` .. ``scan4``). A synthetic subject is a
:class:`SkillProfile` (how it moves) and a seed (which random realisation of it), drawn from the
group's mean profile and spread in ``config/cohort.yaml``. The same cohort seed gives the same
subjects; another seed gives other subjects of the same groups.

Units: m, s, deg where a name says so, Hz.
"""

from dataclasses import dataclass, fields, replace
import math
from pathlib import Path
import zlib

import numpy as np
from sim_bridge.common.configfile import ConfigError, dataclass_from_mapping, load_yaml, section
from sim_bridge.common.paths import config_path

GROUPS = ('experienced', 'naive')


@dataclass(frozen=True)
class SkillProfile:
    """
    How a subject moves the instruments (what the demonstrator adds to the scripted throw).

    Attributes
    ----------
    speed_scale : float
        Factor on every planned speed (1: the scripted expert's pace; < 1 slower).
    aim_std : float
        Entry precision: standard deviation (m) of the offset of the aimed throw circle in the
        surface plane (moves the entry and exit points the needle actually takes).
    tilt_std_deg : float
        Needle-plane alignment: standard deviation (deg) of the turn of the needle plane about
        the surface normal away from the entry-exit line.
    tremor_amplitude : float
        Amplitude (m) of the physiological tremor of the tool tip (free motions).
    tremor_frequency : float
        Tremor frequency (Hz).
    tremor_rotation_deg : float
        Amplitude (deg) of the rotational tremor of the tool.
    wander : float
        Path smoothness: amplitude (m) of the slow deviation of free motions from the straight
        minimum-jerk path (0: perfectly smooth paths).
    wander_frequency : float
        Highest frequency (Hz) of the slow deviation.
    wrist_rotation : float
        Wrist rotation vs translation during the insertion, in [0, 1]: 1 turns the needle about
        its arc centre (pure rotation, no tissue trauma); below 1 part of the turn is replaced by
        pushing the needle along the wound, ``(1 - wrist_rotation) * radius * angle`` at most.
    hesitation_probability : float
        Chance, at each moment both arms are at rest between motions, of a hesitation.
    hesitation_time : float
        Mean length (s) of a hesitation (exponentially distributed).
    entry_pause : float
        Pause (s) with the needle tip on the entry marker before the insertion.
    release_pause : float
        Pause (s) after a jaw let go of the needle before the next motion.
    correction_probability : float
        Chance that a free approach motion overshoots its goal and is corrected.
    correction_distance : float
        Size (m) of an overshoot.
    correction_time : float
        Time (s) the correction back to the goal takes.

    """

    speed_scale: float = 1.0
    aim_std: float = 0.0
    tilt_std_deg: float = 0.0
    tremor_amplitude: float = 0.0
    tremor_frequency: float = 9.0
    tremor_rotation_deg: float = 0.0
    wander: float = 0.0
    wander_frequency: float = 0.5
    wrist_rotation: float = 1.0
    hesitation_probability: float = 0.0
    hesitation_time: float = 0.0
    entry_pause: float = 0.3
    release_pause: float = 0.3
    correction_probability: float = 0.0
    correction_distance: float = 0.0
    correction_time: float = 0.3

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not math.isfinite(value):
                raise ValueError(f'skill profile {f.name} must be a finite number, got {value!r}')
            if value < 0.0:
                raise ValueError(f'skill profile {f.name} must be >= 0, got {value!r}')
        for name in ('speed_scale', 'tremor_frequency', 'wander_frequency'):
            if not getattr(self, name) > 0.0:
                raise ValueError(f'skill profile {name} must be > 0, got {getattr(self, name)}')
        for name in _FRACTIONS:
            if getattr(self, name) > 1.0:
                raise ValueError(f'skill profile {name} must be in [0, 1], got '
                                 f'{getattr(self, name)}')


_FRACTIONS = ('wrist_rotation', 'hesitation_probability', 'correction_probability')


@dataclass(frozen=True)
class Subject:
    """
    One synthetic study subject.

    Attributes
    ----------
    name : str
        ``'S01'``, ``'S02'``, ...
    group : str
        ``'experienced'`` or ``'naive'``.
    seed : int
        Seed of the subject's own randomness (its demonstrations, see :meth:`trial_seed`).
    profile : SkillProfile
        How the subject moves.

    """

    name: str
    group: str
    seed: int
    profile: SkillProfile

    def trial_seed(self, pair: str, attempt: int = 0) -> int:
        """
        Return the seed of this subject's demonstration on a pair.

        Parameters
        ----------
        pair : str
            Marker pair name (``'synth1'``).
        attempt : int
            Repeat number (a failed demonstration is done again).

        Returns
        -------
        int
            Seed in ``[0, 2**32)``, the same for the same subject, pair and attempt.

        """
        key = [self.seed, zlib.crc32(str(pair).encode()), int(attempt)]
        return int(np.random.SeedSequence(key).generate_state(1)[0])


@dataclass(frozen=True)
class GroupSpec:
    """
    One group of the cohort (``groups`` entry of ``config/cohort.yaml``).

    Attributes
    ----------
    name : str
        ``'experienced'`` or ``'naive'``.
    count : int
        Number of subjects.
    profile : SkillProfile
        Mean profile of the group.
    spread : dict of str to float
        Relative spread of profile fields between subjects: a subject's value is the mean times
        ``exp(s * N(0, 1))`` (fractions in [0, 1] are clipped); fields not listed do not vary.

    """

    name: str
    count: int
    profile: SkillProfile
    spread: dict[str, float]


@dataclass(frozen=True)
class StudyDesign:
    """
    The study's design: the groups and the pairs each subject sutures, in order.

    Attributes
    ----------
    groups : tuple of GroupSpec
        Groups in the order their subjects are numbered.
    phantoms : dict of str to tuple of str
        Phantom name -> its marker pairs in the order they are sutured.

    """

    groups: tuple[GroupSpec, ...]
    phantoms: dict[str, tuple[str, ...]]

    @property
    def trials(self) -> list[tuple[str, str]]:
        """List of ``(phantom, pair)`` in the order every subject demonstrates them."""
        return [(phantom, pair) for phantom, pairs in self.phantoms.items() for pair in pairs]


def load_study_design(path: str | Path | None = None) -> StudyDesign:
    """
    Read the study design from ``config/cohort.yaml``.

    Parameters
    ----------
    path : str or Path, optional
        YAML file; default the installed ``cohort.yaml``.

    Returns
    -------
    StudyDesign

    Raises
    ------
    sim_bridge.common.configfile.ConfigError
        Naming the file, the key and what was expected.

    """
    path = config_path('cohort.yaml') if path is None else path
    source = str(path)
    top = load_yaml(path)
    data = section(top, 'cohort', source=source)
    unknown = sorted(set(data) - {'groups', 'phantoms'})
    if unknown:
        raise ConfigError(f'{source}: unknown key cohort.{unknown[0]!r}; expected groups, '
                          'phantoms')
    groups = data.get('groups')
    if not isinstance(groups, list) or not groups:
        raise ConfigError(f'{source}: key cohort.groups must be a non-empty list of groups')
    specs = []
    for k, entry in enumerate(groups):
        key = f'cohort.groups[{k}]'
        if not isinstance(entry, dict):
            raise ConfigError(f'{source}: key {key} must be a mapping')
        spec = dataclass_from_mapping(GroupSpec, {**entry, 'profile': entry.get('profile', {}),
                                                  'spread': entry.get('spread') or {}},
                                      source=source, prefix=key)
        if spec.name not in GROUPS:
            raise ConfigError(f'{source}: key {key}.name must be one of {list(GROUPS)}, '
                              f'got {spec.name!r}')
        if spec.count < 0:
            raise ConfigError(f'{source}: key {key}.count must be >= 0, got {spec.count}')
        names = {f.name for f in fields(SkillProfile)}
        for field_name, value in spec.spread.items():
            if field_name not in names:
                raise ConfigError(f'{source}: unknown key {key}.spread.{field_name!r}; expected '
                                  f'a skill profile field ({sorted(names)})')
            if value < 0.0:
                raise ConfigError(f'{source}: key {key}.spread.{field_name} must be >= 0, '
                                  f'got {value}')
        specs.append(spec)
    phantoms = section(top, 'cohort.phantoms', source=source)
    order = {}
    for name, pairs in phantoms.items():
        if not isinstance(pairs, list) or not pairs or not all(isinstance(p, str)
                                                               for p in pairs):
            raise ConfigError(f'{source}: key cohort.phantoms.{name} must be a non-empty list '
                              f'of marker pair names')
        order[str(name)] = tuple(pairs)
    if not order:
        raise ConfigError(f'{source}: key cohort.phantoms must name at least one phantom')
    return StudyDesign(groups=tuple(specs), phantoms=order)


def _draw_profile(spec: GroupSpec, rng: np.random.Generator) -> SkillProfile:
    values: dict[str, float] = {}
    for f in fields(SkillProfile):
        mean = getattr(spec.profile, f.name)
        s = spec.spread.get(f.name, 0.0)
        value = mean * math.exp(s * rng.standard_normal()) if s > 0.0 else mean
        if f.name in _FRACTIONS:
            value = min(max(value, 0.0), 1.0)
        values[f.name] = float(value)
    return replace(spec.profile, **values)


def subject_seed(cohort_seed: int, index: int) -> int:
    """Return the seed of subject ``index`` (0-based) of the cohort drawn with ``cohort_seed``."""
    return int(np.random.SeedSequence([int(cohort_seed), int(index)]).generate_state(1)[0])


def load_cohort(path: str | Path | None = None, seed: int = 0) -> list[Subject]:
    """
    Draw the cohort of the study design: every subject's seed and skill profile.

    Parameters
    ----------
    path : str or Path, optional
        ``cohort.yaml``; default the installed one (the paper's 4 experienced, 6 naive).
    seed : int
        Cohort seed: the same seed gives the same subjects, another seed other subjects.

    Returns
    -------
    list of Subject
        ``S01`` .. in the order of the groups in the file.

    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f'cohort seed must be a non-negative integer, got {seed!r}')
    design = load_study_design(path)
    subjects: list[Subject] = []
    for spec in design.groups:
        for _ in range(spec.count):
            index = len(subjects)
            own = subject_seed(seed, index)
            profile = _draw_profile(spec, np.random.default_rng(own))
            subjects.append(Subject(name=f'S{index + 1:02d}', group=spec.name, seed=own,
                                    profile=profile))
    return subjects
