"""
Grasp choice: which grasp of the needle keeps every pose of a holding phase reachable.

A grasp is an arc parameter along the needle (0 tail, 1 tip) and a jaw roll about the wire
(:meth:`sim_bridge.common.needle.NeedleGeometry.grasp_transform`). :class:`GraspPlanner` tries
every roll (and, with :meth:`GraspPlanner.choose_grasp_along`, nearby arc parameters) and keeps
the one whose tool path, approach included, is reachable by the arm's closed-form inverse
kinematics with the smallest wrist angles, without an IK branch switch or a roll past its
limits, and with the closed jaw kept off the tissue where asked.

Frames: ``world``; poses 4x4 ``T_world_*``; metres, radians.
"""

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
import functools
import math
from typing import TYPE_CHECKING, cast

import numpy as np
from sim_bridge.common.geometry import invert_transform
from sim_bridge.common.vocabulary import PSMS as ARMS
from suture_lfd.planning.tracks import backed_off, dense_poses

if TYPE_CHECKING:
    from sim_bridge.common.needle import NeedleGeometry
    from sim_bridge.control import ExpertConfig, Observation
    from sim_bridge.kinematics import PsmKinematics
    from sim_bridge.scene.phantom import MarkerPair

# What decides whether the arms reach a throw, and where a user changes it.
PROBE_STRIDE = 6  # carrying poses solved per candidate before its full path: every 6th
# a candidate left unsolved has a lower bound this far (rad) above the best full cost
PROBE_MARGIN = 1e-6
UNREACHABLE_ADVICE = ('try another needle start (the simulator parameter seed), or bring the '
                      'pair between the arms: move the phantom (its position and quaternion in '
                      'the phantom file) or the arm bases (world.arms.<ARM> in world.yaml)')


@dataclass(frozen=True, eq=False)
class GraspPhase:
    """
    What a grasp must keep reachable: one arm's holding phase.

    Attributes
    ----------
    start : ndarray (4, 4) or None
        Tool pose the arm comes from to take the grasp (None: it already holds the needle).
    roll0 : float
        The arm's roll joint (rad) at ``start``.
    grasp_at : ndarray (4, 4)
        Needle pose where the grasp closes.
    paths : sequence of callable
        Needle paths carried afterwards (poses of ``sigma`` in [0, 1]).
    clear : sequence of ndarray (4, 4)
        Needle poses where the closed jaw must keep ``jaw_clearance`` off the surface plane.
    bases : dict of str to ndarray (4, 4)
        ``T_world_base`` per arm.

    """

    start: np.ndarray | None
    roll0: float
    grasp_at: np.ndarray
    paths: Sequence[Callable[[float], np.ndarray]]
    clear: tuple
    bases: dict


@functools.lru_cache(maxsize=256)
def _grasp_candidates(needle: 'NeedleGeometry', s: float, step: float
                      ) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
    """
    Return the candidate grasps at arc parameter ``s`` and their inverses (read-only arrays).

    Every jaw roll ``step`` apart (smallest roll first), unflipped then flipped, as
    :meth:`sim_bridge.common.needle.NeedleGeometry.grasp_transform` gives them; kept for the
    next throws of the process (the same pair gives the same arc parameters).
    """
    rolls = sorted(np.arange(-math.pi, math.pi - 1e-9, step), key=abs)
    grasps = tuple(needle.grasp_transform(s, roll=roll, flip=flip)
                   for flip in (False, True) for roll in rolls)
    invs = tuple(invert_transform(G) for G in grasps)
    for T in grasps + invs:
        T.setflags(write=False)
    return grasps, invs


class GraspPlanner:
    """
    Choose reachable grasps of the needle for the arms, on one marker pair.

    Parameters
    ----------
    pair : sim_bridge.scene.phantom.MarkerPair
        Target pair (its surface plane keeps the jaw clear).
    needle_geometry : sim_bridge.common.needle.NeedleGeometry
        Needle geometry.
    config : sim_bridge.control.ExpertConfig
        ``roll_step_deg``, ``approach_distance``, ``jaw_length``, ``jaw_half_width``,
        ``jaw_clearance``.
    kinematics : sim_bridge.kinematics.PsmKinematics or dict, optional
        PSM kinematics (one for both arms or one per arm); default:
        :func:`sim_bridge.kinematics.psm_kinematics`.

    """

    def __init__(self, pair: 'MarkerPair', needle_geometry: 'NeedleGeometry',
                 config: 'ExpertConfig',
                 kinematics: 'PsmKinematics | dict[str, PsmKinematics] | None' = None) -> None:
        self.pair = pair
        self.needle = needle_geometry
        self.config = config
        if kinematics is None:
            from sim_bridge.kinematics import psm_kinematics
            kinematics = psm_kinematics()
        self.kinematics = (dict(kinematics) if isinstance(kinematics, dict)
                           else dict.fromkeys(ARMS, kinematics))

    def path_cost(self, arm: str, T_world_base: Mapping[str, np.ndarray], roll0: float,
                  tools: Sequence[np.ndarray]) -> tuple[float, float | None]:
        """
        Return the cost of a dense tool path for an arm whose roll joint starts at ``roll0``.

        The path must be reachable everywhere, must not switch IK branches between samples,
        and its continuous roll (as an arm servoing along it reaches it) must stay inside the
        roll limits. Returns ``(largest wrist angle (rad), final roll)``, or ``(inf, None)``.
        """
        chain = self.kinematics[arm]
        T_base_world = invert_transform(T_world_base[arm])
        Q, ok = chain.ik_batch(np.einsum('ij,njk->nik', T_base_world, np.asarray(tools)))
        return self.joint_path_cost(chain, Q, ok, roll0)

    @staticmethod
    def joint_path_cost(chain: 'PsmKinematics', Q: np.ndarray, ok: np.ndarray,
                        roll0: float) -> tuple[float, float | None]:
        """Return :meth:`path_cost` of a path already solved (joints ``Q``, ``ok`` reachable)."""
        if not ok.all():
            return math.inf, None
        roll = np.unwrap(Q[:, 3])
        roll += 2.0 * math.pi * round((roll0 - roll[0]) / (2.0 * math.pi))
        margin = 0.2
        if roll.max() > chain.upper[3] - margin or roll.min() < chain.lower[3] + margin:
            return math.inf, None
        if len(Q) > 1 and np.abs(np.diff(Q[:, [0, 1, 2, 4, 5]], axis=0)).max() > 0.3:
            return math.inf, None
        return float(np.abs(Q[:, 4:6]).max()), float(roll[-1])

    def start_roll(self, arm: str, obs: 'Observation') -> float:
        """Return the roll joint (rad) of ``arm`` in the observation (measured, else by IK)."""
        q = getattr(obs, 'q', None)
        if q is not None and arm in q:
            return float(np.asarray(q[arm])[3])
        chain = self.kinematics[arm]
        T = invert_transform(obs.T_world_base[arm]) @ np.asarray(obs.T_world_tool[arm])
        return float(chain.ik(T)[3])

    def jaw_clearance(self, tools: Sequence[np.ndarray]) -> float:
        """Return the lowest height (m) of the closed jaw's outline above the surface plane."""
        c = self.config
        L, w = c.jaw_length, c.jaw_half_width
        outline = np.array([[0.0, 0.0, 0.0, 1.0], [0.0, 0.0, L, 1.0], [w, 0.0, L, 1.0],
                            [-w, 0.0, L, 1.0], [w, 0.0, 0.0, 1.0], [-w, 0.0, 0.0, 1.0]])
        pts = np.einsum('nij,kj->nki', np.asarray(tools), outline)[..., :3]
        return float(((pts - self.pair.midpoint) @ self.pair.normal).min())

    def choose_grasp(self, arm: str, s: float, phase: GraspPhase, what: str
                     ) -> tuple[np.ndarray, float]:
        """
        Return the grasp at arc parameter ``s`` that keeps a holding phase reachable.

        Parameters
        ----------
        arm : str
            Arm.
        s : float
            Arc parameter of the grasp.
        phase : GraspPhase
            What the grasp must keep reachable.
        what : str
            Phase name for error messages.

        Returns
        -------
        grasp : ndarray, shape (4, 4)
            ``T_tool_needle``.
        roll : float
            Roll joint (rad) at the end of the phase.

        """
        c = self.config
        needles = np.array([path(x) for path in phase.paths for x in np.linspace(0.0, 1.0, 12)])
        chain = self.kinematics[arm]
        T_base_world = invert_transform(phase.bases[arm])
        grasps, invs = _grasp_candidates(self.needle, float(s), math.radians(c.roll_step_deg))
        carried = (needles[None] @ np.asarray(invs)[:, None]).reshape(-1, 4, 4)
        carried = np.einsum('ij,njk->nik', T_base_world, carried)
        costs = self._candidate_costs(chain, phase, carried, len(needles), invs, T_base_world)
        best, best_cost, best_roll = None, math.inf, None
        for k, (cost, end_roll) in sorted(costs.items()):
            if cost < best_cost - 1e-9:
                best, best_cost, best_roll = grasps[k], cost, end_roll
        if best is None:
            raise ValueError(f'{arm} cannot reach a grasp at arc parameter {s:.2f} for '
                             f'{what} of pair {self.pair.name}; {UNREACHABLE_ADVICE}')
        return best.copy(), cast(float, best_roll)  # a finite cost comes with its roll

    def _candidate_costs(self, chain: 'PsmKinematics', phase: GraspPhase, carried: np.ndarray,
                         n_c: int, invs: Sequence[np.ndarray], T_base_world: np.ndarray
                         ) -> dict[int, tuple[float, float | None]]:
        """
        Return ``{candidate: (cost, end roll)}`` of the grasp candidates that can be the best.

        A candidate's cost (:meth:`joint_path_cost` of its approach and carrying path, plus the
        jaw clearance penalty) is at least the largest wrist angle of any of its carrying poses.
        So every candidate's carrying path is first solved at every :data:`PROBE_STRIDE`-th
        pose only: a candidate with one unreachable pose there is out, and the wrist angles
        there bound its cost from below. Then candidates are solved in full (approach
        included) in the order of their bounds until every candidate left has a bound above
        the lowest full cost by more than :data:`PROBE_MARGIN`. A candidate left out costs
        more than the best by more than the choice's tolerance (1e-9) even when the choice
        passes through every candidate, so the choice is that of solving every candidate in
        full. The IK of a pose does not depend on the other poses of a batch.

        Parameters
        ----------
        chain : sim_bridge.kinematics.PsmKinematics
        phase : GraspPhase
        carried : ndarray, shape (K * n_c, 4, 4)
            Carrying tool poses of the K candidates in the base frame, ``n_c`` each.
        n_c : int
            Carrying poses per candidate.
        invs : list of ndarray (4, 4)
            ``T_needle_tool`` per candidate.
        T_base_world : ndarray, shape (4, 4)

        """
        c = self.config
        n_k = len(invs)
        probe = np.arange(0, n_c, PROBE_STRIDE)
        Qp, okp = chain.ik_batch(carried[(np.arange(n_k)[:, None] * n_c + probe).ravel()])
        okp = cast(np.ndarray, okp.reshape(n_k, -1).all(axis=1))  # one flag per candidate
        bound = np.abs(Qp[:, 4:6]).reshape(n_k, -1).max(axis=1)
        order = [k for k in np.argsort(np.where(okp, bound, np.inf), kind='stable') if okp[k]]
        costs, lowest, done, size = {}, math.inf, 0, 2
        while done < len(order) and bound[order[done]] <= lowest + PROBE_MARGIN:
            batch = order[done:done + size]
            done += len(batch)
            size *= 2
            poses, spans = [carried[k * n_c:(k + 1) * n_c] for k in batch], []
            if phase.start is not None:
                for k in batch:
                    grasp_pose = phase.grasp_at @ invs[k]
                    pre = backed_off(grasp_pose, c.approach_distance)
                    path = dense_poses(phase.start, pre) + dense_poses(pre, grasp_pose)
                    spans.append(len(path))
                    poses.append(np.einsum('ij,njk->nik', T_base_world, np.asarray(path)))
            Q, ok = chain.ik_batch(np.concatenate(poses))
            ends = np.cumsum([len(batch) * n_c] + spans)
            for j, k in enumerate(batch):
                Qk, okk = Q[j * n_c:(j + 1) * n_c], ok[j * n_c:(j + 1) * n_c]
                if not okk.all():
                    continue
                if spans:
                    a, b = ends[j], ends[j + 1]
                    Qk, okk = np.concatenate((Q[a:b], Qk)), np.concatenate((ok[a:b], okk))
                cost, end_roll = self.joint_path_cost(chain, Qk, okk, phase.roll0)
                if phase.clear and math.isfinite(cost):
                    low = self.jaw_clearance([N @ invs[k] for N in phase.clear])
                    cost += 1000.0 * max(0.0, c.jaw_clearance - low)
                costs[int(k)] = (cost, end_roll)
                lowest = min(lowest, cost)
        return costs

    def choose_grasp_along(self, arm: str, s: float, span: Sequence[float],
                           phase: GraspPhase, what: str, candidates: int = 9
                           ) -> tuple[np.ndarray, float, float]:
        """
        Return a reachable grasp at arc parameter ``s`` or, failing that, the nearest in ``span``.

        Parameters
        ----------
        arm : str
            Arm.
        s : float
            Preferred arc parameter (0 tail, 1 tip).
        span : tuple of float
            ``(lo, hi)``: arc parameters the grasp may move to.
        phase : GraspPhase
            What the grasp must keep reachable.
        what : str
            Phase name for error messages.
        candidates : int
            Arc parameters of the span tried besides ``s``.

        Returns
        -------
        grasp : ndarray, shape (4, 4)
            ``T_tool_needle``.
        roll : float
            Roll joint (rad) at the end of the phase.
        s : float
            Arc parameter of the chosen grasp.

        Raises
        ------
        ValueError
            If no arc parameter of the span gives a reachable grasp (the message names the span).

        """
        lo, hi = float(span[0]), float(span[1])
        others = np.linspace(lo, hi, candidates) if hi > lo else np.array([])
        ordered = [float(s)] + sorted((float(x) for x in others if abs(x - s) > 1e-6),
                                      key=lambda x: abs(x - s))
        first = None
        for x in ordered:
            try:
                G, roll = self.choose_grasp(arm, x, phase, what)
            except ValueError as exc:
                first = exc if first is None else first
                continue
            return G, roll, x
        raise ValueError(f'{first}; no arc parameter in [{lo:.2f}, {hi:.2f}] is reachable '
                         f'either') from first

    def held_grasp(self, arm: str, obs: 'Observation',
                   paths: Sequence[Callable[[float], np.ndarray]], what: str
                   ) -> tuple[np.ndarray, float]:
        """
        Return the grasp the arm holds the needle with, checked along the needle paths.

        Parameters
        ----------
        arm : str
            Arm (in ``obs.holders``).
        obs : sim_bridge.control.Observation
            Start state.
        paths : list of callable
            Needle paths the arm must carry the needle along.
        what : str
            Phase name for the error message.

        Returns
        -------
        grasp : ndarray, shape (4, 4)
            Measured ``T_tool_needle``.
        roll : float
            Roll joint (rad) at the end of the paths.

        Raises
        ------
        ValueError
            If the paths leave the arm's reach with this grasp.

        """
        G = invert_transform(obs.T_world_tool[arm]) @ np.array(obs.T_world_needle, dtype=float)
        _, roll = self.path_cost(
            arm, obs.T_world_base, self.start_roll(arm, obs),
            [N @ invert_transform(G) for path in paths
             for N in (path(x) for x in np.linspace(0.0, 1.0, 12))])
        if roll is None:
            raise ValueError(f'{arm} cannot carry the needle it holds through {what} of pair '
                             f'{self.pair.name}; regrasp it first')
        return G, roll
