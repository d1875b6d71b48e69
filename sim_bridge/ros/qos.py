"""
The QoS profiles of every topic of the project, defined once, each with the reason for it.

A subscription matches a publisher when it asks for no more than the publisher offers
(reliable/transient-local publishers serve reliable/volatile subscribers too). Depth is the
``KEEP_LAST`` history: how many messages wait for a slow reader before the oldest is dropped.
"""

from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

# Values that describe a state and change rarely (operating state, base frames, markers, a
# node's status and result): a late subscriber must get the current one at once, and only the
# newest matters.
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)

# The simulator's scene events (grasp, release, entry, exit, score, ...): a client that joins
# during a throw must see every event of it, so the whole history of a throw (well under 1000
# events) is kept for late subscribers.
SCENE_EVENTS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.TRANSIENT_LOCAL)

# An arm's or a pedal's events (error, warning, status, goal reached, pedal presses): rare,
# each one meaningful; the last 100 are kept for a late subscriber (a dVRK client that starts
# after the arm still sees why it is disabled).
EVENTS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.TRANSIENT_LOCAL)

# Published state streams (measured_cp, measured_js, needle pose, /tf, visualization): sent at
# the simulation rate (up to 100 Hz); a depth of 100 lets a reader that stalls for about a
# second catch up without losses. Volatile: an old state is of no use to a late subscriber.
STATE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                   durability=DurabilityPolicy.VOLATILE)

# Streams whose reader acts on the newest message: a client's subscriptions to the arms' state
# and its own commands (demonstrator, executor, teleop, SimClient), the virtual MTMs' state.
# 10 queued messages are plenty.
STREAM = QoSProfile(depth=10)

# A client's servo streams (servo_cp, jaw/servo_jp): the arm takes only the newest goal, but a
# recorder takes every one, and a publisher's history is all a reader that stalls for a moment
# can catch up from; 1000 goals cover a second at 1 kHz (depth 10 lost 16 % of a
# demonstration's goals on a busy machine).
SERVO_STREAM = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE)

# Commands a node receives (state commands, pedal emulation, target pair, stats): reliable so
# none is lost, 10 deep for a burst, volatile since a stale command must not be replayed.
COMMANDS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)

# The streamed goals an arm receives (servo_*, jaw/servo_*): only the newest target counts; an
# older one still queued would drive the arm backwards.
ARM_COMMANDS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE)

# Commands an arm or a virtual MTM applies one by one, in order (state commands, moves, hold,
# free, settings): a burst is queued, never dropped (the dVRK simulators' contract: an ordered
# queue of up to 32; a latched state command fills both readers of sim_bridge.ros.intake, hence
# 100). Volatile, so that every publisher matches.
QUEUED_COMMANDS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.VOLATILE)

# The second reader of a state_command topic (sim_bridge.ros.intake): transient-local, so that a
# command a latched publisher (crtk) sent before discovery matched it still arrives; stale ones
# are dropped by the intake, not by the QoS.
LATCHED_COMMANDS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                              durability=DurabilityPolicy.TRANSIENT_LOCAL)

# How a client publishes state commands: latched, as crtk does, so that one sent before
# discovery completes is not lost, and a volatile publisher does not meet the receiver's
# transient-local reader (rclpy warns of incompatible QoS there).
STATE_COMMAND = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL)

# /clock as the simulator and the player publish it: every tick reaches the subscribers that
# keep up (use_sim_time nodes, the recorder).
CLOCK = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                   durability=DurabilityPolicy.VOLATILE)

# /clock as a watchdog reads it (executor): only the newest time matters, and a backlog drained
# after a stall must not outrun the measured_cp queued behind it.
CLOCK_LATEST = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)

# /tf_static: every static transform is published once; a late subscriber (a viewer opened
# mid-run) must get all of them, so a deep transient-local history, as tf2 itself keeps.
STATIC_TF = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)

# Camera images: large; a viewer wants the newest frame, and two let one be read while the next
# arrives.
IMAGES = QoSProfile(depth=2, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.VOLATILE)

# Streams of input devices (a browser's or a viewer's hand poses and grippers): the newest
# reading is all that counts, and a lost one is replaced by the next within milliseconds, so
# best effort, one deep (a reader that falls behind skips to the newest reading instead of
# working through stale ones: at 200 Hz, 10 deep was 50 ms of lag), volatile.
SENSOR = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT,
                    durability=DurabilityPolicy.VOLATILE)

# State streams of which a reader keeps only the newest value between its cycles (the teleop's
# MTM, PSM and camera poses, gripper and jaw): one deep, so that a reader starved of CPU for a
# moment takes the newest sample at once instead of the 10 queued before it.
LATEST = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.VOLATILE)


# No QoS-event handlers on a busy node's endpoints (the simulator's ~160, the pedals', the
# virtual MTMs'): rclpy's executor visits each handler at every wake-up (1 kHz with a streaming
# client), which cost more than the simulation itself, and half of the MTMs node's CPU; a client
# with incompatible QoS or type is still warned by its own endpoints.
_QUIET_PUBLISHER = PublisherEventCallbacks(use_default_callbacks=False)
_QUIET_SUBSCRIPTION = SubscriptionEventCallbacks(use_default_callbacks=False)


class QuietEndpoints:
    """Node mix-in: publishers and subscriptions without the default QoS-event handlers."""

    def create_publisher(self, *args, **kwargs):
        kwargs.setdefault('event_callbacks', _QUIET_PUBLISHER)
        return super().create_publisher(*args, **kwargs)  # type: ignore[misc]

    def create_subscription(self, *args, **kwargs):
        kwargs.setdefault('event_callbacks', _QUIET_SUBSCRIPTION)
        return super().create_subscription(*args, **kwargs)  # type: ignore[misc]
