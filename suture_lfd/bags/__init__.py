"""
rosbag2 bags of demonstrations: typestore, writing, reading, inspection and recovery.

A bag is a rosbag2 directory, as ``ros2 bag`` writes it: ``metadata.yaml`` (format version 9) and
one MCAP file with profile ``ros2`` and ``ros2msg`` schemas, so that ``ros2 bag play``, Foxglove
and the ``mcap`` tools read it. Messages are stored as CDR bytes with their time stamps in
nanoseconds (receive time of the recorder's clock: wall time, or sim time with
``use_sim_time``). Message types are ROS 2 Jazzy's plus ``crtk_msgs`` and ``tf2_msgs``, read
from the ``.msg`` files the package installs (``share/suture_lfd/interfaces/<pkg>/msg``), so this
module works without ROS.

Crash safety: :class:`BagWriter` closes an MCAP chunk every ``chunk_seconds`` or ``chunk_bytes``
and pushes it to the operating system, so a writer killed mid-recording (``SIGKILL``, power is
another story) leaves an MCAP file whose complete chunks hold every message written up to the
last flush, but no ``metadata.yaml`` and no MCAP summary. Recover it with::

    suture-lfd bag recover PATH [--out OUT]

which reads the records of ``PATH`` (the bag directory or its ``.mcap`` file) one after the other,
stops cleanly at the first truncated or corrupt record, and writes a new, valid bag to ``OUT``
(default: ``PATH-recovered`` next to it) holding every message of the complete chunks.
``suture-lfd bag info PATH`` prints the topics, types, counts and duration of a bag.

Integrity: the MCAP files carry CRC-32s of every chunk, of the data section and of the summary
(:mod:`suture_lfd.bags.mcap_check`). Opening a bag checks them all, and that ``metadata.yaml``
agrees with the MCAP summary, so a flipped byte is refused before any message is read;
``bag recover`` keeps the chunks whose CRC holds and says which it dropped.

Errors about a bag (missing ``metadata.yaml``, truncated or corrupt file, a message that does not
decode, missing topics) raise :class:`BagError`, a ``ValueError`` whose one-line message names the
file, the topic and the byte offset or time stamp where known, and says what to do.
"""


from suture_lfd.bags.format import (
    INTERFACE_PACKAGES,
    METADATA,
    ROS_DISTRO,
    ensure_type,
    interface_definitions,
    make_qos,
    make_typestore,
    qos_fields,
)
from suture_lfd.bags.reader import (
    BagMessage,
    BagReader,
    BagSummary,
    TopicSummary,
    bag_custom_data,
    bag_summary,
    format_summary,
    open_bag,
)
from suture_lfd.bags.recovery import recover_bag
from suture_lfd.bags.writer import (
    CHUNK_BYTES,
    CHUNK_SECONDS,
    BagWriter,
    joint_state_cdr,
    pose_stamped_cdr,
)
from suture_lfd.errors import BagError

__all__ = [
    'BagError', 'BagMessage', 'BagReader', 'BagSummary', 'BagWriter', 'CHUNK_BYTES',
    'CHUNK_SECONDS', 'INTERFACE_PACKAGES', 'METADATA', 'ROS_DISTRO', 'TopicSummary',
    'bag_custom_data', 'bag_summary', 'ensure_type', 'format_summary', 'interface_definitions',
    'joint_state_cdr', 'make_qos', 'make_typestore', 'open_bag', 'pose_stamped_cdr',
    'qos_fields', 'recover_bag',
]
