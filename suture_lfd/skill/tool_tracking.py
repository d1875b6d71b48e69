"""
The tool brought onto its plan from where it is seen: an integral loop on the tool's pose.

Why. On a dVRK-like arm (cable play and stretch, a servo that lags, wrist offsets the
registration leaves) a corrected command does not put the tool where it was sent: during the
insertion the tool the controller sees (the registered correction of the reported joints,
accurate to a few tenths of a millimetre) passes 1-2 mm from the planned path, where on the
static-offset robots it passes within 0.02 mm. The belief is good; the commands miss. A
person at the console closes this loop by eye; here :class:`ToolTracking` does: during the
DMP subtasks it compares each arm's tool as seen with the target it was sent ``delay`` ago (the
servo's own lag left out) and takes the difference up into a bias added to the next targets,
with time constant ``tau`` (an integral action, position and orientation), bounded.

Reads only what the controller observes (the corrected tool poses); off unless
``ExecutorConfig.track_tool`` asks for it.

Frames: ``world``; 4x4 poses; metres, radians, seconds.
"""

from collections import deque

import numpy as np
from sim_bridge.common.vocabulary import TASKS
from sim_bridge.control import Command, Controller, Observation
from suture_lfd.planning.waypoints import rotation_exp, rotation_log


class ToolTracking:
    """
    A controller whose tool targets are biased until the tools as seen reach them.

    Parameters
    ----------
    controller : object
        ``reset(obs)``, ``step(obs) -> Command``, ``done``; given the observations as they
        come (the tools where the correction puts them).
    delay : float
        Age (s) of the target a tool seen now is compared with (about the servo's lag).
    tau : float
        Time constant (s) of the bias's integral.
    max_shift, max_turn : float
        Bounds of the bias (m, rad).
    subtasks : tuple of str
        Subtask labels tracked; elsewhere the bias is dropped and targets pass unchanged.

    """

    def __init__(self, controller: Controller, delay: float = 0.1, tau: float = 1.0,
                 max_shift: float = 0.003, max_turn: float = 0.1,
                 subtasks: tuple[str, ...] = TASKS) -> None:
        self.controller = controller
        self.delay, self.tau = float(delay), float(tau)
        self.max_shift, self.max_turn = float(max_shift), float(max_turn)
        self.subtasks = tuple(subtasks)
        self._sent: dict[str, deque[tuple[float, np.ndarray]]] = {}
        self._last: dict[str, np.ndarray] = {}
        self._bias: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._t: float | None = None

    @property
    def done(self) -> bool:
        """Whether the controller is done."""
        return self.controller.done

    def reset(self, obs: Observation) -> None:
        """Reset the controller and drop the biases."""
        self._sent.clear()
        self._last.clear()
        self._bias.clear()
        self._t = None
        self.controller.reset(obs)

    def _target_then(self, arm: str, t: float) -> np.ndarray | None:
        """Return the target ``arm`` was sent ``delay`` before ``t`` (or the oldest kept)."""
        sent = self._sent.get(arm)
        if not sent:
            return None
        while len(sent) > 1 and sent[1][0] <= t - self.delay + 1e-9:
            sent.popleft()
        return sent[0][1]

    def step(self, obs: Observation) -> Command:
        """Return the controller's command with each tracked tool target biased."""
        cmd = self.controller.step(obs)
        t = float(obs.t)
        dt = 0.0 if self._t is None else max(0.0, t - self._t)
        self._t = t
        tools = dict(cmd.T_world_tool)
        for arm, T in tools.items():
            if T is not None:
                self._last[arm] = np.asarray(T, dtype=float)
            target = self._last.get(arm)
            if cmd.subtask not in self.subtasks or target is None:
                self._bias.pop(arm, None)
                self._sent.pop(arm, None)
                continue
            shift, turn = self._bias.get(arm, (np.zeros(3), np.zeros(3)))
            then = self._target_then(arm, t)
            seen = obs.T_world_tool.get(arm)
            if then is not None and seen is not None and dt > 0.0:
                seen = np.asarray(seen, dtype=float)
                gain = min(1.0, dt / self.tau)
                shift = shift + gain * (then[:3, 3] - seen[:3, 3])
                turn = turn + gain * rotation_log(then[:3, :3] @ seen[:3, :3].T)
                n = float(np.linalg.norm(shift))
                if n > self.max_shift:
                    shift = shift * (self.max_shift / n)
                a = float(np.linalg.norm(turn))
                if a > self.max_turn:
                    turn = turn * (self.max_turn / a)
            self._bias[arm] = (shift, turn)
            self._sent.setdefault(arm, deque()).append((t, target))
            biased = target.copy()
            biased[:3, :3] = rotation_exp(turn) @ target[:3, :3]
            biased[:3, 3] = target[:3, 3] + shift
            tools[arm] = biased
        return Command(t=cmd.t, T_world_tool=tools, jaw=cmd.jaw, subtask=cmd.subtask)
