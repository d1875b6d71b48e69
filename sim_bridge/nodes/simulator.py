"""
The simulator node: the simulated dVRK scene behind the dVRK 2.x CRTK ROS 2 interface.

Runs :class:`sim_bridge.simulation.Simulation` and gives each arm (``PSM1``, ``PSM2``, ``ECM``) the
topics, services and events of a physical dVRK (:mod:`sim_bridge.nodes.crtk_arm`), so a dVRK client
drives it unchanged; adds the scene's ground truth, ``/tf``, visualization and the ECM stereo
camera (:mod:`sim_bridge.nodes.scene_topics`), each arm's URDF on ``<ARM>/robot_description``
(:mod:`sim_bridge.nodes.robot_description`), the console foot pedals
(:mod:`sim_bridge.nodes.footpedals`), and:

- ``sim/events`` (crtk_msgs/StringStamped, RELIABLE, TRANSIENT_LOCAL, depth 1000): one JSON
  object per scene event, ``{"kind": ..., "t": <s since the scene started>, ...}``, kinds
  ``grasp``, ``release``, ``entry``, ``exit``, ``withdrawn``, ``extracted``, ``trauma``, ``drop``,
  ``collision``, ``score``, ``reset``, ``target_pair``; stamped with the simulator clock;
- ``sim/target_pair`` (std_msgs/String, subscribed): the marker pair scored next;
- ``sim/stats`` (std_msgs/String, JSON, every second of wall time): the requested
  ``real_time_factor``, the factor ``achieved`` over the last second, simulation seconds
  ``skipped`` so far because the loop fell behind, ``sim_time`` and ``clock``;
- ``sim/process`` (std_msgs/String, JSON, latched): the node's pid, host and process start
  time (:func:`sim_bridge.ros.peer.announcement`), so a client on this machine can tell a
  starved simulator from a dead one;
- ``sim/reset`` (std_srvs/Trigger): restart the scene (arms DISABLED at rest, needle on the pad;
  the needle start is seeded with ``seed + number of resets``).

Physical mode (``physical: true``): the node shows only what a physical dVRK shows. The scene's
ground truth (needle, markers, phantom, the arms' true bases, the scene events and the
visualization) is published only under ``/evaluation/`` (``/evaluation/sim/needle/measured_cp``,
``/evaluation/sim/events``, ...), which the pipeline's nodes never read; ``/tf`` carries no
needle and ``/tf_static`` the arms' bases as the robot believes them (no phantom or markers).
``kinematic_error_level`` (mm class, 0: none) gives the PSMs hidden, seeded kinematic errors
(:mod:`sim_bridge.kinematic_errors`): the arms report poses consistent with their commands while
the tools are really elsewhere.

Arms keep the dVRK's operating-state timings by default: ``enable`` powers up for
``power_up_time`` before ENABLED, and ``home`` moves an arm from its rest pose (``psm_rest_jp``,
``ecm_rest_jp``: retracted) to the homing goal in seconds, busy meanwhile; ``power_up_time: 0``
and ``start_at_home: true`` make both take one step.

Time: the node owns it. Every ``tick`` the simulation is stepped (fixed physics step) up to
``real_time_factor`` times the wall time elapsed (0: as fast as it goes); when it falls more than
``max_lag`` wall seconds behind it skips the backlog instead of bursting. ``/clock`` carries the
simulator clock, ``clock_start + simulation time`` (``clock_start < 0``: the wall clock at
start-up, so that at ``real_time_factor`` 1 clients without ``use_sim_time`` see current stamps);
every stamp the node publishes is on that clock; state topics are published every ``1/rate``
seconds of simulation time. Other nodes run with ``use_sim_time:=true``.

Threads: the simulation is stepped, and its state published, by a stepping thread of its own
that keeps to its schedule (like the dVRK's control loop); the executor thread runs every other
callback (commands, services) and sleeps in ``rcl_wait`` otherwise. Both hold
:attr:`Simulator.lock` while they touch the simulation. Streaming commands (``servo_*``, up to
1 kHz from a teleoperation client) do not wake the executor: each stepping round takes the newest
of each before it steps, as the dVRK applies servo goals in its control loop; any other command
first takes the servo commands that arrived before it, so commands keep their order. (rclpy's
executor rebuilds its wait set of the node's ~150 endpoints at each wake-up, about 0.4 ms of
Python; stepping from a timer paid that 500 times a second.) Parameters:
``config/simulator.yaml``.

Size: one node (its parameters, its stepping round and the services it offers); the per-arm and
scene topics are in modules of their own.
"""

from dataclasses import dataclass, replace
import gc
import json
import math
import sys
import threading
import time
import traceback

from crtk_msgs.msg import StringStamped
import numpy as np
from rclpy.node import Node
from rosgraph_msgs.msg import Clock as ClockMsg
from sim_bridge.common.validation import check_positive
from sim_bridge.common.vocabulary import PSMS
from sim_bridge.nodes import executables
from sim_bridge.nodes.crtk_arm import CrtkArm
from sim_bridge.nodes.footpedals import FootPedals
from sim_bridge.nodes.robot_description import RobotDescriptions
from sim_bridge.nodes.scene_topics import SceneTopics, truth_topic
from sim_bridge.realism.calibration import ARM_LEVELS, load_arm_realism
from sim_bridge.realism.endoscope import endoscope_preset
from sim_bridge.realism.tissue_config import load_tissue_realism
from sim_bridge.ros import conversions as cv
from sim_bridge.ros import qos
from sim_bridge.ros.entry import NodeHooks
from sim_bridge.ros.params import declare_config
from sim_bridge.ros.peer import announcement
from sim_bridge.scene.world import FRAMES
from sim_bridge.simulation import ARMS, Simulation, load_simulation_config
from std_msgs.msg import String
from std_srvs.srv import Trigger

STATS_PERIOD = 1.0  # s of wall time between sim/stats messages


@dataclass(frozen=True)
class SimulatorConfig:
    """
    Parameters of the simulator node (names as in ``config/simulator.yaml``).

    Attributes
    ----------
    phantom : str
        ``'synthetic'``, ``'scanned'`` (phantoms of the scene), an STL/OBJ/PLY mesh path
        (metres, z up; markers laid on its top surface) or a phantom file (``.yaml``: mesh,
        scale, pose, wound line or markers).
    scene : str
        Scene file replacing the installed ``scene.yaml`` (``''``: the installed one).
    seed : int
        Seed of the scene (needle start pose).
    target_pair : str
        Marker pair scored first (``''``: the phantom's first pair).
    real_time_factor : float
        Simulated seconds per wall second; 0 = as fast as possible.
    rate : float
        State publishing rate (Hz of simulation time); the dVRK publishes at 100 Hz.
    tf_rate, visualization_rate, camera_rate : float
        Rates (Hz of simulation time) of ``/tf``, ``sim/visualization`` and the stereo images;
        0 = off. The pair is rendered only while someone subscribes to it.
    camera_width, camera_height : int
        Image size (pixels) of the stereo pair; 0: ``world.yaml``'s (the field of view is
        kept).
    camera_depth : bool
        Also publish each eye's metric depth (``ECM/<eye>/depth``, 32FC1, m).
    clock_start : float
        Simulator clock (s) when the simulation starts; < 0: the wall clock at start-up.
    tick : float
        Wall time (s) between stepping rounds (at most; shorter when rate x factor needs it);
        ``servo_*`` commands wait for the next round.
    max_lag : float
        Wall time (s) the simulation may fall behind before it skips the backlog.
    clock_rate : float
        ``/clock`` messages per second of wall time, at most (one per stepping round below
        it): every node on ``use_sim_time`` handles each one.
    tracking : str
        ``'limited'`` (joints follow setpoints within the dVRK limits) or ``'exact'``.
    tool_present : bool
        PSM instruments mounted at start-up.
    power_up_time : float
        Simulated time (s) from ``enable`` to ENABLED (DISABLED and busy meanwhile, as a dVRK
        arm powering its amplifiers, which it must do within 3 s); 0: at once.
    start_at_home : bool
        Start (and restart on ``sim/reset``) the arms at the homing goal, so that ``home`` ends
        at once; false: at ``psm_rest_jp`` / ``ecm_rest_jp``, and ``home`` is a trajectory of a
        few seconds at the joint trajectory limits, as on a dVRK.
    psm_rest_jp, ecm_rest_jp : tuple of float
        Rest poses of the PSMs (6 joints) and the ECM (4 joints), rad / m; default all zeros
        (the pose a simulated dVRK arm powers up in: instrument and endoscope retracted to the
        cannula, insertion 0).
    footpedals : bool
        Run the console foot pedals (``/footpedals/*``) in this process.
    frames : str
        Frames of the arms' Cartesian poses: ``cart`` (a patient cart: PSM poses in the ECM
        camera frame ``ECM``, the ECM in ``world``, the set-up joints' ``SUJ/*`` topics),
        ``base`` (each arm in its RCM frame ``<ARM>_base``), ``''``: ``world.frames`` of
        ``config/world.yaml``.
    physical : bool
        Publish the ground truth only under ``/evaluation/`` (see the module docstring).
    kinematic_error_level : float
        Class (mm, >= 0) of the PSMs' hidden kinematic errors; 0: perfect kinematics.
    kinematic_error_seed : int
        Seed of the kinematic errors' draw.
    camera_realism : str
        The endoscope's preset in ``config/realism_camera.yaml`` (``dvrk``: a distorting lens,
        30 Hz, 50 ms latency); ``''``: an ideal camera at ``camera_rate``, stamped when rendered.
    tissue : str
        Needle-in-tissue realism preset of ``config/realism_tissue.yaml`` (``none``: off;
        ``tissue``: tissue forces, the needle turning in the jaw, a pad that gives).
    arm_realism : str
        ``'static'`` (the offsets of ``kinematic_error_level``) or a preset of
        ``config/realism_arm.yaml`` (``'dvrk'``: calibration errors, cable transmission, servo
        lag, encoders, the ECM's reported pose, the endoscope's intrinsics), drawn with
        ``kinematic_error_seed``.
    arm_realism_levels : str
        Levels overriding the preset's, ``'encoder_level=0,ecm_level=0.5'`` (keys of
        :data:`sim_bridge.realism.calibration.ARM_LEVELS`); ``''``: the preset's own.

    """

    phantom: str = 'synthetic'
    scene: str = ''
    seed: int = 0
    target_pair: str = ''
    real_time_factor: float = 1.0
    rate: float = 100.0
    tf_rate: float = 50.0
    visualization_rate: float = 10.0
    camera_rate: float = 0.0
    camera_width: int = 0
    camera_height: int = 0
    camera_depth: bool = False
    clock_start: float = -1.0
    tick: float = 0.002
    max_lag: float = 0.25
    clock_rate: float = 200.0
    tracking: str = 'limited'
    tool_present: bool = True
    footpedals: bool = True
    power_up_time: float = 1.0
    start_at_home: bool = False
    psm_rest_jp: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    ecm_rest_jp: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)
    frames: str = ''
    physical: bool = False
    kinematic_error_level: float = 0.0
    kinematic_error_seed: int = 0
    camera_realism: str = ''
    tissue: str = 'none'
    arm_realism: str = 'static'
    arm_realism_levels: str = ''

    def __post_init__(self):
        self.levels()  # a malformed arm_realism_levels stops the node here, naming it
        if not (math.isfinite(self.real_time_factor) and self.real_time_factor >= 0):
            raise ValueError(f'parameter real_time_factor must be >= 0 (0: as fast as possible), '
                             f'got {self.real_time_factor}')
        for name in ('rate', 'clock_rate'):
            check_positive(getattr(self, name), f'parameter {name} (Hz)')
        for name in ('tf_rate', 'visualization_rate', 'camera_rate'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f'parameter {name} must be >= 0 Hz (0: off), got {value}')
        for name in ('tick', 'max_lag'):
            check_positive(getattr(self, name), f'parameter {name} (s)')
        for name in ('camera_width', 'camera_height'):
            if getattr(self, name) < 0:
                raise ValueError(f"parameter {name} must be >= 0 pixels (0: world.yaml's), "
                                 f'got {getattr(self, name)}')
        if not (math.isfinite(self.power_up_time) and self.power_up_time >= 0):
            raise ValueError(f'parameter power_up_time must be >= 0 s (0: at once), '
                             f'got {self.power_up_time}')
        for name, n in (('psm_rest_jp', 6), ('ecm_rest_jp', 4)):
            value = getattr(self, name)
            if len(value) != n or not all(math.isfinite(float(v)) for v in value):
                raise ValueError(f'parameter {name} must be {n} finite joint values (rad / m), '
                                 f'got {list(value)}')
        if self.frames not in ('', *FRAMES):
            raise ValueError(f"parameter frames must be 'cart', 'base' or '' (world.yaml's), "
                             f'got {self.frames!r}')
        if not (math.isfinite(self.kinematic_error_level) and self.kinematic_error_level >= 0):
            raise ValueError(f'parameter kinematic_error_level must be >= 0 (mm class, 0: no '
                             f'error), got {self.kinematic_error_level}')
        if self.tracking not in ('limited', 'exact'):
            raise ValueError(f"parameter tracking must be 'limited' or 'exact', "
                             f'got {self.tracking!r}')

    def levels(self) -> dict[str, float]:
        """
        Return ``arm_realism_levels`` as ``{level key: value}``.

        Raises
        ------
        ValueError
            If an entry is not ``key=number`` with a key of ``ARM_LEVELS`` and a number >= 0.

        """
        out = {}
        for entry in filter(None, (e.strip() for e in self.arm_realism_levels.split(','))):
            key, _, value = entry.partition('=')
            key = key.strip()
            try:
                number = float(value)
            except ValueError:
                number = math.nan
            if key not in ARM_LEVELS or not (math.isfinite(number) and number >= 0.0):
                raise ValueError(f'parameter arm_realism_levels must be key=level entries '
                                 f'separated by commas, the keys among {", ".join(ARM_LEVELS)} '
                                 f'and the levels >= 0, got {entry!r}')
            out[key] = number
        return out


class _Every:
    """Fires when simulation time crosses a multiple of ``1/rate`` (never for rate 0)."""

    def __init__(self, rate):
        self.rate = rate
        self.last = -1

    def due(self, t):
        if not self.rate:
            return False
        k = int(t * self.rate + 1e-6)
        if k != self.last:
            self.last = k
            return True
        return False


class _FootPedals(qos.QuietEndpoints, FootPedals):
    """The console foot pedals, sharing the simulator's executor."""


class _Locked:
    """The simulator's lock, held by a callback (see :meth:`Simulator.locked`)."""

    __slots__ = ('node',)

    def __init__(self, node):
        self.node = node

    def __enter__(self):
        node = self.node
        node._waiting += 1
        node.lock.acquire()
        node._waiting -= 1

    def __exit__(self, *exc):
        self.node.lock.release()


class Simulator(qos.QuietEndpoints, NodeHooks, Node):
    """The simulated dVRK: CRTK arms, scene ground truth, events, time."""

    def __init__(self):
        super().__init__('simulator')
        self.config = cfg = declare_config(self, SimulatorConfig, 'simulator.yaml', 'simulator')
        sim_config = load_simulation_config(scene_path=cfg.scene or None)
        rest = {} if cfg.start_at_home else {
            'psm_rest_jp': tuple(float(v) for v in cfg.psm_rest_jp),
            'ecm_rest_jp': tuple(float(v) for v in cfg.ecm_rest_jp)}
        if cfg.frames:
            sim_config = replace(sim_config, world=replace(sim_config.world, frames=cfg.frames))
        sim_config = replace(
            sim_config,
            arm=replace(sim_config.arm, tracking=cfg.tracking, tool_present=cfg.tool_present,
                        power_up_time=float(cfg.power_up_time)),
            loop=replace(sim_config.loop, target_pair=cfg.target_pair or None),
            kinematic_error_level=float(cfg.kinematic_error_level),
            kinematic_error_seed=int(cfg.kinematic_error_seed),
            endoscope=endoscope_preset(cfg.camera_realism),
            arm_realism=(None if cfg.arm_realism == 'static'
                         else load_arm_realism(cfg.arm_realism, levels=cfg.levels())),
            camera=replace(sim_config.camera, depth=cfg.camera_depth,
                           width=cfg.camera_width or sim_config.camera.width,
                           height=cfg.camera_height or sim_config.camera.height), **rest)
        if cfg.tissue != 'none':
            sim_config = replace(sim_config, tissue_realism=load_tissue_realism(cfg.tissue))
        self.sim = Simulation(sim_config, rng=np.random.default_rng(cfg.seed),
                              phantom=cfg.phantom)
        self._resets = 0
        self._pair = self.sim.target_pair.name
        self._dt_ns = int(round(self.sim.dt * 1e9))
        start = time.time() if cfg.clock_start < 0 else cfg.clock_start
        self._t0_ns = max(int(round(start * 1e9)), 1)
        self._state = _Every(cfg.rate)
        self._state_ns = None  # stamp of the state published in this step, if any
        self._tf = _Every(cfg.tf_rate)
        self._viz = _Every(cfg.visualization_rate)
        # an endoscope with a frame rate exposes at it (while camera_rate asks for images) and
        # its frames reach ROS its latency later
        self._frame_timing = timing = sim_config.endoscope.timing
        self._camera = _Every(timing.rate if timing.rate and cfg.camera_rate else cfg.camera_rate)
        self._rtf = cfg.real_time_factor
        # a round every half state period (at most every tick); as fast as it goes: 1 ms
        period = 0.001 if self._rtf == 0 else max(0.001, min(cfg.tick,
                                                            0.5 / (cfg.rate * self._rtf)))
        # steps per round: four rounds' worth, so the loop catches up after a slow round but
        # never holds the executor (and the command callbacks) for long; as fast as it goes:
        # four state periods per round
        paced = period * self._rtf if self._rtf > 0 else 1.0 / cfg.rate
        self._chunk = max(1, int(math.ceil(4 * max(paced, period) / self.sim.dt)))
        self._max_behind = int(math.ceil(cfg.max_lag * max(self._rtf, 1.0) / self.sim.dt))
        self._anchor_wall = None  # set by the first stepping round
        self._anchor_sim = self.sim.time
        self.skipped = 0.0  # simulation seconds dropped because the loop fell behind
        self._stepped = 0
        self._stats_wall = time.monotonic()
        self._clock_wall, self._clock_period = -math.inf, 1.0 / cfg.clock_rate - 1e-4

        self._clock_pub = self.create_publisher(ClockMsg, '/clock', qos.CLOCK)
        self._events_pub = self.create_publisher(StringStamped, truth_topic('sim/events',
                                                                            cfg.physical),
                                                 qos.SCENE_EVENTS)
        self._stats_pub = self.create_publisher(String, 'sim/stats', qos.COMMANDS)
        # who runs the simulation, so that a client on this machine tells a starved simulator
        # (silent, but its process exists) from a dead one (sim_bridge.ros.peer)
        self._process_pub = self.create_publisher(String, 'sim/process', qos.LATCHED)
        self._process_pub.publish(String(data=announcement()))
        # held by the stepping thread for a round and by every callback that touches the scene
        self.lock = threading.RLock()
        self._waiting = 0  # callbacks waiting for the lock: the stepping thread lets them in
        # at real time on the wall clock, clients without use_sim_time compare operating_state
        # stamps with their system clock: those stamps never fall behind it
        wall = time.time_ns if cfg.clock_start < 0 and self._rtf == 1.0 else None
        cart = sim_config.world.frames == 'cart'
        self.arms = {name: CrtkArm(self, name, lambda n=name: self.sim.arms[n], self.now_ns,
                                   on_command=self._flush_arm_events, poll_servo=True,
                                   lock=self.locked, stamp_floor_ns=wall,
                                   T_world_base=self.sim.believed_base(name), suj=cart,
                                   read_jp=(lambda n=name: self.sim.reported_jp(n))
                                   if self.sim.physics.has_encoders else None,
                                   read_jaw=(lambda n=name: self.sim.reported_jaw(n))
                                   if self.sim.physics.has_jaw_stall and name in PSMS else None)
                     for name in ARMS}
        self.scene = SceneTopics(self, self.sim, depth=cfg.camera_depth, physical=cfg.physical)
        self.create_subscription(String, 'sim/target_pair', self._on_target_pair, qos.COMMANDS)
        self.create_service(Trigger, 'sim/reset', self._on_reset)
        self.robot_descriptions = RobotDescriptions(self, self.sim)

        stamp = self.stamp()
        self._clock_pub.publish(cv.clock_message(stamp))
        self.scene.publish_latched(stamp)
        for face in self.arms.values():
            face.publish_operating_state()
        self._publish_event('target_pair', self.sim.time, pair=self._pair)
        self._period = period
        self._stop = threading.Event()
        self._stepper = None
        self.failure = None  # the exception that stopped the stepping thread, if any
        if self.sim.phantom.placement:
            self.get_logger().info(f'phantom {self.sim.phantom.name}: '
                                   f'{self.sim.phantom.placement}')
        # the console foot pedals, spun on the simulator's executor
        self.companions = [_FootPedals()] if cfg.footpedals else []
        self.get_logger().info(
            f'simulating {cfg.phantom} phantom, pairs {", ".join(self.sim.phantom.markers)}, '
            f'pair {self._pair}, real-time factor {self._rtf or "max"}, state at '
            f'{cfg.rate:g} Hz')

    # -- time ----------------------------------------------------------------------------------

    def now_ns(self):
        """Return the simulator clock now (int ns): ``clock_start + simulation time``."""
        return self._t0_ns + int(round(self.sim.time * 1e9))

    def stamp(self, t=None):
        """Return the stamp of simulation time ``t`` (s, default now) on the simulator clock."""
        if t is None:
            return cv.stamp_from_nanoseconds(self.now_ns())
        return cv.stamp_from_nanoseconds(self._t0_ns + int(round(t * 1e9)))

    def locked(self):
        """
        Context manager: hold :attr:`lock` (for callbacks run by the executor thread).

        Marks the caller as waiting, so the stepping thread, which otherwise takes the lock
        back at once when it runs as fast as it goes, yields it between rounds.
        """
        return _Locked(self)

    def start(self):
        """Start the stepping thread (once the node is added to its executor)."""
        self._stepper = threading.Thread(target=self._run, name='simulator-stepping',
                                         daemon=True)
        self._stepper.start()

    def stop(self):
        """Stop the stepping thread and wait for it."""
        self._stop.set()
        if self._stepper is not None:
            self._stepper.join()

    def _run(self):
        """Step a round every ``period`` of wall time on a fixed schedule (stepping thread)."""
        period, stop = self._period, self._stop
        deadline = time.monotonic()
        while not stop.is_set():
            try:
                with self.lock:
                    self._advance()
            except Exception as exc:  # noqa: BLE001 (reported, then the node stops)
                if not self.context.ok():
                    return  # SIGINT/SIGTERM shut the context down mid-round: stop quietly
                self.failure = exc
                self.get_logger().fatal(f'simulation stopped: {exc!r}\n{traceback.format_exc()}')
                self.context.try_shutdown()
                return
            deadline += period
            delay = deadline - time.monotonic()
            if delay > 0:
                stop.wait(delay)
            else:
                deadline = time.monotonic()  # behind: the next round now, no burst of rounds
                if self._waiting:
                    time.sleep(50e-6)  # let a waiting callback take the lock

    def _advance(self):
        """Step the simulation up to the wall clock times the real-time factor; publish."""
        sim = self.sim
        wall = time.monotonic()
        if self._anchor_wall is None:
            # the first round: simulation time starts now (start-up work is not simulated)
            self._anchor_wall, self._anchor_sim = wall, sim.time
            if self.config.clock_start < 0:
                self._t0_ns = max(self._t0_ns, time.time_ns() - int(round(sim.time * 1e9)))
        if self._rtf > 0:
            behind = int((self._anchor_sim + self._rtf * (wall - self._anchor_wall) - sim.time)
                         / sim.dt + 1e-6)
            if behind > self._max_behind:
                # too far behind the wall clock: drop the backlog rather than burst through it
                self.skipped += (behind - self._chunk) * sim.dt
                self._anchor_wall, self._anchor_sim = wall, sim.time + self._chunk * sim.dt
                behind = self._chunk
            n = min(behind, self._chunk)
        else:
            n = self._chunk
        if n:
            for face in self.arms.values():
                face.take_commands()
        for _ in range(n):
            self._step()
        if n and wall - self._clock_wall >= self._clock_period:
            self._clock_pub.publish(cv.clock_message(self.stamp()))
            self._clock_wall = wall
        self._stepped += n
        if wall - self._stats_wall >= STATS_PERIOD:
            self._publish_stats(wall)

    def _publish_stats(self, wall):
        """Publish ``sim/stats``: the loop's pace over the last period (JSON)."""
        span = wall - self._stats_wall
        simulated = self._stepped * self.sim.dt
        stats = {'real_time_factor': self._rtf, 'achieved': simulated / span,
                 'skipped': self.skipped, 'simulated': simulated, 'wall': span,
                 'sim_time': self.sim.time, 'clock': self.now_ns() * 1e-9}
        self._stats_pub.publish(String(data=json.dumps(stats, sort_keys=True)))
        self._stats_wall, self._stepped = wall, 0

    def _step(self):
        sim = self.sim
        self._state_ns = None
        sim.step(after_arms=self._publish_arm_state)
        self._flush_arm_events()
        self._flush_sim_events()
        t = sim.time
        if self._state_ns is not None:
            self.scene.publish_state(self._state_ns)
        if self._tf.due(t):
            self.scene.publish_tf(self.stamp())
        if self._viz.due(t):
            self.scene.publish_visualization(self.stamp())
        if self._camera.due(t):
            self.scene.expose_camera(t, t + self._frame_timing.latency)
        self.scene.publish_camera(t, self.stamp)

    def _publish_arm_state(self):
        """Publish the arms' state when it is due: called as soon as the arms have moved."""
        if self._state.due(self.sim.time):
            self._state_ns = ns = self.now_ns()
            for face in self.arms.values():
                face.publish_state(ns)

    # -- events --------------------------------------------------------------------------------

    def _flush_arm_events(self):
        for face in self.arms.values():
            face.flush_events()

    def _flush_sim_events(self):
        for event in self.sim.pop_events():
            self._publish_event(event.kind, event.t, **event.data)

    def _publish_event(self, kind, t, **data):
        self._events_pub.publish(cv.event_message(kind, self.stamp(t), t=t, **data))

    # -- scene commands ------------------------------------------------------------------------

    def _on_target_pair(self, msg):
        with self.locked():
            self._set_target_pair(msg)

    def _set_target_pair(self, msg):
        try:
            self.sim.set_target_pair(msg.data)
        except ValueError as exc:
            self.get_logger().error(f'sim/target_pair: {exc}')
            self._publish_event('target_pair', self.sim.time, pair=msg.data, error=str(exc))
            return
        self._pair = msg.data
        self._publish_event('target_pair', self.sim.time, pair=self._pair)

    def _on_reset(self, request, response):
        with self.locked():
            return self._reset(response)

    def _reset(self, response):
        sim = self.sim
        self._flush_arm_events()
        self._flush_sim_events()
        # the clock goes on: the new scene starts one physics step after the old one's end
        self._t0_ns = self.now_ns() + self._dt_ns
        self._resets += 1
        sim.reset(seed=self.config.seed + self._resets)
        sim.set_target_pair(self._pair)
        for every in (self._state, self._tf, self._viz, self._camera):
            every.last = -1
        self._anchor_wall, self._anchor_sim = time.monotonic(), sim.time
        for face in self.arms.values():
            face.publish_operating_state()
        self._publish_event('reset', sim.time, resets=self._resets)
        self._publish_event('target_pair', sim.time, pair=self._pair)
        self.scene.publish_latched(self.stamp())
        self._clock_pub.publish(cv.clock_message(self.stamp()))
        # the old scene is garbage, the new one lives on: collect once, keep the collector off
        # the new scene (as after start-up, sim_bridge.ros.entry)
        gc.unfreeze()
        gc.collect()
        gc.freeze()
        response.success = True
        response.message = f'scene reset ({self._resets}), target pair {self._pair}'
        return response

    @property
    def exit_code(self):
        """Return the process exit code: 1 when the stepping thread failed, else 0."""
        return 1 if self.failure is not None else 0

    def on_start(self):
        """Start stepping once the node spins (the entry point calls it)."""
        self.start()

    def on_exit(self):
        """Stop the stepping thread, then release the simulation (PyBullet)."""
        self.stop()
        self.close()

    def close(self):
        """Release the simulation (PyBullet)."""
        self.sim.close()


def main(args=None):
    return executables.simulator(args)


if __name__ == '__main__':
    sys.exit(main())
