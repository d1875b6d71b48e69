"""
A scripted person at the viewer page: performs one throw through the virtual MTMs.

The operator's intent is a synthetic study subject's (:class:`suture_lfd.demos.demonstrator.
Demonstrator`, built on the pipeline's expert planner): the tool poses and jaw angles it wants.
The operator reaches them the way a person at a dVRK console does, with the hands only: it moves
the viewer's 6-DOF handles (``viewer/input/<MTM>/pose``, ``world``) and grippers, which the
virtual MTMs and two ``teleop`` nodes turn into PSM motion at a fifth of the hand's. Its hands
tremble (``TREMOR`` m at 8.7 Hz plus noise low-passed at ``NOISE_HZ``: a hand does not move at
the 200 Hz of its samples), except while the needle is in the tissue, which steadies them (as
the synthetic subjects' model has it). The needle is in the tissue from the simulator's
``entry`` event to its ``extracted`` (or ``drop``) event, as the operator sees it, and during
the plan's insertion and extraction (subtasks ii and iv): the tool lags the plan by the
teleoperation's latency, so with the plan alone the hands trembled again while the tip was
still at the exit, and it backed out of its puncture ("withdrawn") on a busy machine. When a
hand leaves its ``WORKSPACE`` (m around where it started), and before the needle goes into the
tissue (subtasks ii and iv, during which it reaches ``IN_TISSUE_REACH`` times as far rather
than let go), it presses the clutch pedal, brings both hands back and releases it. When a
tool stays short of its goal it moves that hand to take up the error (``CORRECTION_GAIN``). It
presses coag (``viewer/input/pedals``) to be present and pinches the grippers once so that the
teleoperation starts. The recorder's pedal is pressed before and after, as the demonstrator
node does (its stages and result are this node's; only the hands differ).

Run as a script: ``python scripted_operator.py --ros-args -p subject:=S01 -p pair:=synth1``.
"""

import sys

from geometry_msgs.msg import PoseStamped
import numpy as np
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Joy
from sim_bridge.ros import conversions as cv
from sim_bridge.ros.entry import run_node
from std_msgs.msg import Float64, String
from suture_lfd.nodes.demonstrator import DemonstratorNode
from suture_lfd.teleop.mapping import GripperToJaw

MTM_OF = {'PSM1': 'MTMR', 'PSM2': 'MTML'}
TELEOP_OF = {'PSM1': 'MTMR_PSM1', 'PSM2': 'MTML_PSM2'}
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
STATE = QoSProfile(depth=10)
SCALE = 0.2
WORKSPACE = 0.05          # m of hand travel from the rest position before clutching
TREMOR = 0.0004           # m amplitude of the hand's tremor at TREMOR_HZ
TREMOR_HZ = 8.7
NOISE_HZ = 12.0           # cut-off of the tremor's noise (a physiological tremor's band)
RECENTRE_TIME = 0.4       # s to bring the hands back with the clutch pressed
IN_TISSUE_REACH = 4.0     # times WORKSPACE a hand reaches while the needle is in the tissue
CORRECTION_GAIN = 1.5     # 1/s: how fast the operator takes up an error it sees
MAX_CORRECTION = 0.004    # m of tool
STUCK_TIME = 0.5          # s the subject's clock waits on a lagging tool before correcting


class ScriptedOperator(DemonstratorNode):
    """The demonstrator's throw, performed with the hands through the virtual MTMs."""

    def __init__(self):
        super().__init__()
        self._rng = np.random.default_rng(self.config.seed + 1000)
        self._phase = self._rng.uniform(0, 2 * np.pi, size=(2, 3))
        self._noise = np.zeros((2, 3))
        self._noise_t = None
        self._in_tissue = False       # between the simulator's entry and extracted events
        self._jaw_map = GripperToJaw()
        self._hand_pub = {a: self.create_publisher(PoseStamped, f'viewer/input/{m}/pose', STATE)
                          for a, m in MTM_OF.items()}
        self._grip_pub = {a: self.create_publisher(Float64, f'viewer/input/{m}/gripper', STATE)
                          for a, m in MTM_OF.items()}
        self._pedal_pub = self.create_publisher(Joy, 'viewer/input/pedals', STATE)
        self._teleop_state = {}
        for arm, name in TELEOP_OF.items():
            self.create_subscription(String, f'/{name}/current_state',
                                     lambda m, a=arm: self._teleop_state.__setitem__(a, m.data),
                                     LATCHED)
        self._setpoint = {}           # in <ARM>_base, as every dVRK reports local/setpoint_cp
        for arm in MTM_OF:
            self.create_subscription(PoseStamped, f'{arm}/local/setpoint_cp',
                                     lambda m, a=arm: self._setpoint.__setitem__(
                                         a, cv.matrix_from_pose(m.pose)), STATE)
        self._hands, self._home, self._anchor, self._grippers = {}, {}, {}, {}
        self._clutch = self._coag = False
        self._clutching = None            # (stage, wall time, start hands)
        self._gesture = 0
        self._bias = {a: np.zeros(3) for a in MTM_OF}
        self._stuck = self._lag_seen = 0.0
        self.sim.send = self._send          # the subject's commands go to the hands instead
        self._recentred_for = None
        self.clutches = 0

    # --- the operator's body ----------------------------------------------------------------

    def _on_event(self, stamp, data):
        kind = data.get('kind')
        if kind == 'entry':
            self._in_tissue = True
        elif kind in ('extracted', 'drop'):
            self._in_tissue = False
        super()._on_event(stamp, data)

    def _press(self, topic, value):
        if topic == self.config.operator_pedal:
            self._coag = bool(value)
            return
        super()._press(topic, value)

    def _tool_setpoint(self, arm):
        return self.sim.bases[arm] @ self._setpoint[arm]

    def _publish_hands(self):
        stamp = self.get_clock().now().to_msg()
        t = self.get_clock().now().nanoseconds * 1e-9
        # the tissue steadies the hands while the needle is in it (as the subjects' model)
        steady = self._in_tissue or (self._dem is not None and self._dem.subtask in ('ii', 'iv'))
        amplitude = 0.0 if steady else TREMOR
        dt = 0.0 if self._noise_t is None else max(0.0, t - self._noise_t)
        self._noise_t = t
        keep = np.exp(-2 * np.pi * NOISE_HZ * dt)        # first-order low-pass of white noise
        self._noise = keep * self._noise + np.sqrt(1 - keep * keep) * self._rng.normal(
            0.0, TREMOR * 0.25, (2, 3))
        for k, arm in enumerate(MTM_OF):
            if arm not in self._hands:
                continue
            T = self._hands[arm].copy()
            if amplitude:
                T[:3, 3] += amplitude * np.sin(2 * np.pi * TREMOR_HZ * t + self._phase[k]) \
                    + self._noise[k]
            self._hand_pub[arm].publish(cv.pose_stamped(T, 'world', stamp))
            self._grip_pub[arm].publish(Float64(data=self._grippers[arm]))
        msg = Joy()
        msg.header.stamp = stamp
        msg.buttons = [int(self._clutch), int(self._coag)]
        self._pedal_pub.publish(msg)

    def _following(self):
        return all(self._teleop_state.get(a) == 'FOLLOWING' for a in MTM_OF)

    def _anchor_hands(self):
        # The correction a hand has learnt stays: the tool's setpoint (the anchor) already
        # carries it, and forgetting it here moved the setpoint back by up to MAX_CORRECTION at
        # the clutch before the insertion, backing a tip that the push had put into the tissue
        # out of its puncture ("withdrawn") when the tools lagged on a busy machine.
        for arm in MTM_OF:
            self._anchor[arm] = (self._hands[arm].copy(), self._tool_setpoint(arm))

    def _correct(self):
        """
        Watch the tools: when one has stopped short of where the hand should have brought it
        (the subject's clock has waited on it for ``STUCK_TIME`` s), move that hand to take up
        the error (push or pull harder).
        """
        dem = self._dem
        if dem is None or not dem._last_cmd:
            return
        dt = 1.0 / self.config.rate
        waited = dem.waits['lag']
        if waited > self._lag_seen:
            self._stuck += dt
        else:
            self._stuck = 0.0
        self._lag_seen = waited
        if self._stuck < STUCK_TIME:
            return
        for arm, T_cmd in dem._last_cmd.items():
            error = T_cmd[:3, 3] - self.sim.world_tool(arm)[:3, 3]
            if np.linalg.norm(error) > 0.5 * self.config.lag_tolerance:
                bias = self._bias[arm] + CORRECTION_GAIN * dt * error
                norm = np.linalg.norm(bias)
                self._bias[arm] = bias if norm <= MAX_CORRECTION \
                    else bias * (MAX_CORRECTION / norm)

    def _send(self, command, stamp=None):
        """Move the hands so that the teleoperated tools reach the command (not servo_cp)."""
        for arm in MTM_OF:
            T = command.T_world_tool.get(arm)
            if T is not None and arm in self._anchor:
                hand0, tool0 = self._anchor[arm]
                hand = np.eye(4)
                hand[:3, 3] = hand0[:3, 3] + (T[:3, 3] + self._bias[arm] - tool0[:3, 3]) / SCALE
                hand[:3, :3] = T[:3, :3] @ tool0[:3, :3].T @ hand0[:3, :3]
                self._hands[arm] = hand
            jaw = command.jaw.get(arm)
            if jaw is not None:
                g = self._jaw_map.gripper_from_jaw(jaw)
                self._grippers[arm] = float(np.clip(g, 0.0, self._jaw_map.gripper_max))
        # a person recentres before the needle goes into the tissue, and not while it is in
        subtask = self._dem.subtask if self._dem is not None else 'i'
        in_tissue = subtask in ('ii', 'iv')
        if in_tissue and subtask != self._recentred_for:
            self._recentred_for = subtask
            self._clutching = ('press', 0.0, None)
            return
        reach = WORKSPACE * (IN_TISSUE_REACH if in_tissue else 1.0)
        if any(np.linalg.norm(self._hands[a][:3, 3] - self._home[a][:3, 3]) > reach
               for a in MTM_OF):
            self._clutching = ('press', 0.0, None)

    def _clutch_step(self):
        """Press the clutch, bring both hands back to rest, release, wait for following."""
        stage, t0, start = self._clutching
        wall = self.get_clock().now().nanoseconds * 1e-9
        if stage == 'press':
            self._clutch = True
            if all(self._teleop_state.get(a) == 'CLUTCHED' for a in MTM_OF):
                self._clutching = ('recentre', wall, {a: T.copy() for a, T in self._hands.items()})
                self.clutches += 1
        elif stage == 'recentre':
            s = min(1.0, (wall - t0) / RECENTRE_TIME)
            for arm in MTM_OF:
                self._hands[arm] = start[arm].copy()
                self._hands[arm][:3, 3] = (1 - s) * start[arm][:3, 3] + s * self._home[arm][:3, 3]
            if s >= 1.0:
                self._clutch = False
                self._clutching = ('release', wall, None)
        elif stage == 'release':
            if self._following() and wall - t0 > 0.1:
                self._anchor_hands()
                self._clutching = None

    def _report(self):
        wall = self.get_clock().now().nanoseconds * 1e-9
        if wall - getattr(self, '_reported', 0.0) < 5.0:
            return
        self._reported = wall
        dem = self._dem
        lag = {}
        if dem is not None and self.sim.ready():
            lag = {a: round(float(np.linalg.norm(self.sim.world_tool(a)[:3, 3] - T[:3, 3])), 4)
                   for a, T in dem._last_cmd.items()}
        correction = {a: round(float(np.linalg.norm(b)), 4) for a, b in self._bias.items()}
        self.get_logger().info(
            f'stage {self._stage}, clutching {self._clutching and self._clutching[0]}, '
            f'teleops {self._teleop_state}, anchored {sorted(self._anchor)}, '
            f'plan time {dem.plan_time if dem else None}, waits {dem.waits if dem else None}, '
            f'lag {lag}, correction {correction}')

    def _on_timer(self):
        self._report()
        if not self._hands and self.sim.ready() and all(a in self._setpoint for a in MTM_OF):
            for arm in MTM_OF:               # the handles start at the tools (as the viewer's)
                self._hands[arm] = self.sim.world_tool(arm)
                self._home[arm] = self._hands[arm].copy()
                self._grippers[arm] = 0.6
        if self._hands:
            self._publish_hands()
        if self._stage != 'running':
            super()._on_timer()
            return
        if self._clutching is not None:
            self._clutch_step()
            return
        if not self._anchor:
            if not self._following():        # pinch the grippers: "I am here"
                self._gesture += 1
                for arm in MTM_OF:
                    self._grippers[arm] = 0.6 + (0.12 if self._gesture // 20 % 2 else 0.0)
                return
            self._anchor_hands()
        if not self._following():            # a teleop dropped out: wait for it
            self._anchor = {}
            return
        super()._on_timer()
        self._correct()

    def _finish(self, ok, why='', outcome=None):
        self.get_logger().info(f'operator clutched {self.clutches} times, correction at the end '
                               f'{ {a: np.round(b, 4).tolist() for a, b in self._bias.items()} }')
        super()._finish(ok, why, outcome=outcome)


def main(args=None):
    return run_node(ScriptedOperator, 'demonstrator', args, doc=__doc__,
                    config_file='demonstrator.yaml')


if __name__ == '__main__':
    sys.exit(main())
