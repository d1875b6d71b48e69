"""
One throw in-process: start the episode, run a controller until it is done, let it settle.

:func:`start_episode` resets the scene, enables and homes the arms and selects the pair;
:func:`run_episode` runs the controller and the settling time.

The study's executor throws (:func:`suture_lfd.skill.executor.execute_throw`), the scripted
demonstrations (:mod:`suture_lfd.demos.scripted_demo`), the benchmarks and the tests run their
throws with these two functions. A controller has ``reset(obs)``, ``step(obs) -> Command`` and
``done`` (:mod:`sim_bridge.control`); a recorder wrapping it sees every observation.
"""

from collections.abc import Callable
import math
from typing import TYPE_CHECKING, cast

if TYPE_CHECKING:
    from sim_bridge.control import CommandSource, Controller
    from sim_bridge.scene.phantom import MarkerPair
    from sim_bridge.simulation import Simulation


def start_episode(sim: 'Simulation', pair_name: str, seed: int = 0) -> 'MarkerPair':
    """
    Reset the scene with ``seed``, enable and home the arms, and select the target pair.

    Parameters
    ----------
    sim : sim_bridge.simulation.Simulation
        The simulation.
    pair_name : str
        Marker pair to suture (``'synth1'``).
    seed : int
        Scene seed (needle start).

    Returns
    -------
    sim_bridge.scene.phantom.MarkerPair
        The target pair (``world``).

    """
    sim.reset(seed=seed)
    sim.enable_and_home_all()
    sim.set_target_pair(pair_name)
    return cast('MarkerPair', sim.target_pair)  # set just above


def run_episode(sim: 'Simulation', controller: 'Controller', control_period: float, *,
                stepper: 'CommandSource | None' = None, until: Callable[[], bool] | None = None,
                timeout: float = math.inf, chunk: float = 0.5, settle: float = 0.2,
                always_settle: bool = False, reset: bool = True,
                stop_at_done: bool = False) -> float:
    """
    Run ``controller`` on the simulation until it is done (or ``timeout``), then settle.

    The commands are applied every ``control_period``; whether to stop is checked every
    ``chunk`` seconds, or, with ``stop_at_done``, right after each command is computed.

    Parameters
    ----------
    sim : sim_bridge.simulation.Simulation
        The simulation, after :func:`start_episode`.
    controller : sim_bridge.control.Controller
        ``reset(obs)``, ``step(obs) -> Command`` and ``done``.
    control_period : float
        Seconds of simulation between two commands.
    stepper : sim_bridge.control.CommandSource, optional
        What the simulation calls each control period instead of ``controller`` (a recorder
        that forwards to it, a wrapper that alters its commands); its ``step`` may return
        None (no new command) when ``stop_at_done`` is set.
    until : callable, optional
        ``until() -> bool``: stop when it is true (``controller.done`` by default).
    timeout : float
        Longest run (s of simulation time).
    chunk : float
        Simulation seconds run between two checks of ``done``.
    settle : float
        Seconds run after the controller is done (the scene comes to rest, the score is final).
    always_settle : bool
        Settle even after a timeout.
    reset : bool
        Call ``controller.reset`` with the first observation first.
    stop_at_done : bool
        Stop at the first observation after which the controller is done (or after which
        ``timeout`` is passed), without applying its last command or stepping further: a
        recording that ends on that sample (the demonstrations).

    Returns
    -------
    float
        Simulation seconds from the start to the end of the control loop.

    """
    stepper = controller if stepper is None else stepper
    if until is None:
        def until() -> bool:
            return controller.done
    t_start = sim.time
    if reset:
        controller.reset(sim.observation())
    if stop_at_done:
        while True:
            command = stepper.step(sim.observation())
            if until() or sim.time - t_start > timeout:
                break
            if command is not None:
                sim.apply(command)
            sim.run(control_period)
    else:
        while not until() and sim.time - t_start < timeout:
            sim.run(min(chunk, timeout - (sim.time - t_start)), stepper, control_period)
    elapsed = sim.time - t_start
    if settle > 0.0 and (always_settle or until()):
        sim.run(settle, stepper, control_period)
    return elapsed
