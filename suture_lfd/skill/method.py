"""
The methods a throw skill is learnt and placed by, registered by name in :data:`METHODS`.

:mod:`suture_lfd.skill` describes ``paper`` and ``pair_frame``.
"""

from dataclasses import dataclass

from suture_lfd.dmp.base import REGRESSIONS

ANCHORS = ('arc', 'insertion_arc', 'midpoint', 'markers')


@dataclass(frozen=True)
class Method:
    """
    How a throw skill is learnt and placed on a new pair.

    Attributes
    ----------
    name : str
        Registry name.
    frame : {'world', 'suture', 'arc'}
        Coordinates the DMPs are learnt and rolled out in: ``'arc'`` is, per subtask, the
        needle pose on the pair's needle circle with the tip at the marker the subtask starts
        from (:meth:`PairGeometry.arc_anchor`; entry for ii, exit for iv), so a pair whose
        markers are further apart turns the needle on its own circle, not the demonstrated
        motion's world axes.
    anchors : {'arc', 'insertion_arc', 'midpoint', 'markers'}
        ``'arc'``: the insertion's start carried with the needle pose that has the tip at the
        entry marker on the needle's circle through the pair, its goal and both ends of the
        extraction with the pose that has the tip at the exit marker
        (:meth:`PairGeometry.arc_anchor`); ``'insertion_arc'``: the insertion as ``'arc'``,
        the extraction as ``'midpoint'`` (its goal, out of the tissue, keeps the demonstrated
        direction from the needle's circle in ``world`` axes, which a ``world`` DMP needs to
        keep the demonstrated shape: its ``(g - y0)`` scaling is per axis); ``'midpoint'``:
        start and goal carried rigidly with the pair's suture frame (origin at the midpoint);
        ``'markers'``: the start carried with a frame at the entry marker, the goal with a
        frame at the exit marker (both with the suture frame's axes). ``'midpoint'`` and
        ``'markers'`` keep the demonstrated needle rotation from start to goal, so on a pair
        whose markers are further apart (or closer) than the demonstrated ones the tip misses
        them (``'midpoint'``) or the needle is dragged sideways through the tissue
        (``'markers'``).
    description : str
        One line for reports.
    regression : {'lwr', 'least_squares'}
        How the DMP weights are fitted (``DmpParams.regression``): ``'lwr'`` as the paper,
        ``'least_squares'`` all basis functions together. Task iv's needle centre rests while
        the needle turns about it and moves only in the last sixth of the subtask, when it is
        pulled clear; LWR's overlapping local averages smooth that pull away and the rollout
        ends short of the goal (1.7 mm on average at ``t = T``); the least-squares fit of the
        same Table I bases keeps it (0.05 mm).

    """

    name: str
    frame: str
    anchors: str
    description: str = ''
    regression: str = 'lwr'

    def __post_init__(self) -> None:
        if self.frame not in ('world', 'suture', 'arc'):
            raise ValueError(f"method {self.name}: frame must be 'world', 'suture' or 'arc', "
                             f'got {self.frame!r}')
        if self.regression not in REGRESSIONS:
            raise ValueError(f'method {self.name}: regression must be one of {REGRESSIONS}, '
                             f'got {self.regression!r}')
        if self.anchors not in ANCHORS:
            raise ValueError(f'method {self.name}: anchors must be one of {ANCHORS}, '
                             f'got {self.anchors!r}')


METHODS = {
    'paper': Method('paper', 'world', 'insertion_arc',
                    'seed paper: needle DMPs in world coordinates, start/goal with the tip at '
                    'the entry/exit marker of the new pair'),
    'pair_frame': Method('pair_frame', 'arc', 'arc',
                         'needle DMPs in the frame of the needle circle through the pair, '
                         'start/goal with the tip at the entry/exit marker of the new pair, '
                         'weights fitted by least squares', regression='least_squares'),
}


def get_method(name: 'str | Method') -> 'Method':
    """
    Return the registered :class:`Method` called ``name``.

    Raises
    ------
    ValueError
        If no method has that name (the message lists the registered ones).

    """
    if isinstance(name, Method):
        return name
    if name not in METHODS:
        raise ValueError(f'unknown skill method {name!r}; expected one of {sorted(METHODS)}')
    return METHODS[name]
