"""
What a bag holds besides its messages: the file layout, the message types and the QoS profiles.

The message types are ROS 2 Jazzy's plus ``crtk_msgs`` and ``tf2_msgs``, read from the ``.msg``
files the package installs (``share/suture_lfd/interfaces/<pkg>/msg``), so bags are written and
read without ROS; a bag's topics record the QoS profiles their publishers offered.
"""

from collections.abc import Iterator, Sequence
import functools
import os
from pathlib import Path
import sys
from typing import Any

from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.typesys import Stores, TypesysError, get_types_from_msg, get_typestore
from rosbags.typesys.base import Nodetype
from rosbags.typesys.store import Typestore
from sim_bridge.common.paths import share_dir
from suture_lfd.errors import BagError

INTERFACE_PACKAGES = ('crtk_msgs', 'tf2_msgs')
METADATA = 'metadata.yaml'
ROS_DISTRO = 'jazzy'  # metadata.yaml's ros_distro: the distribution of the message types
_NO_DURATION = QosTime(0, 0)


# --- message types -------------------------------------------------------------------------------

def interface_definitions(root: str | Path | None = None) -> dict[str, str]:
    """
    Return the ``.msg`` text of the package's own interfaces (crtk_msgs, tf2_msgs).

    Parameters
    ----------
    root : str or Path, optional
        Folder holding ``<pkg>/msg/*.msg``; default ``<share>/interfaces`` of the installed
        package (or ``interfaces/`` of a source checkout).

    Returns
    -------
    dict[str, str]
        ``{'crtk_msgs/msg/OperatingState': text, ...}``.

    """
    root = Path(root) if root is not None else share_dir() / 'interfaces'
    found = {}
    for pkg in INTERFACE_PACKAGES:
        for path in sorted((root / pkg / 'msg').glob('*.msg')):
            found[f'{pkg}/msg/{path.stem}'] = path.read_text()
    if not found:
        raise FileNotFoundError(
            f'no interface definitions under {root}: expected <pkg>/msg/*.msg for '
            f'{", ".join(INTERFACE_PACKAGES)}; reinstall the package')
    return found


@functools.lru_cache(maxsize=1)
def _interface_types() -> dict[str, Any]:
    types: dict[str, Any] = {}
    for name, text in interface_definitions().items():
        types.update(get_types_from_msg(text, name))
    return types


def make_typestore() -> Typestore:
    """
    Return a new rosbags typestore: ROS 2 Jazzy plus crtk_msgs and tf2_msgs.

    Returns
    -------
    rosbags.typesys.store.Typestore
        Serialises, deserialises, and gives definitions and RIHS01 hashes. Each call returns
        a new store, so callers may register more types without affecting others.

    """
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(_interface_types())
    return store


def _share_prefixes() -> list[Path]:
    prefixes = [Path(sys.prefix)]
    prefixes += [Path(p) for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    return prefixes


def ensure_type(store: Typestore, msgtype: str, msgdef: str | None = None) -> None:
    """
    Make ``msgtype`` known to ``store``, from ``msgdef`` or from an installed ``.msg`` file.

    Parameters
    ----------
    store : rosbags.typesys.store.Typestore
        Store to extend.
    msgtype : str
        ``'pkg/msg/Name'``.
    msgdef : str, optional
        Definition in the ``ros2msg`` format of rosbag2 (the type's text followed by its
        dependencies, each after a line of 80 ``=`` and ``MSG: pkg/Name``).

    Raises
    ------
    BagError
        If the type is unknown and no definition is given or installed.

    """
    if msgtype in store.fielddefs:
        return
    if not msgdef:
        pkg, _, name = msgtype.partition('/msg/')
        for prefix in _share_prefixes():
            path = prefix / 'share' / pkg / 'msg' / f'{name}.msg'
            if path.is_file():
                msgdef = path.read_text()
                break
    if not msgdef:
        raise BagError(
            f'message type {msgtype!r} is unknown: it is not a ROS 2 Jazzy, crtk_msgs or '
            f'tf2_msgs type and no share/{msgtype.split("/")[0]}/msg file is installed')
    types = get_types_from_msg(msgdef, msgtype)
    try:
        store.register(types)
    except TypesysError as exc:
        raise BagError(f'message type {msgtype!r}: {exc}') from exc
    for _, desc in types[msgtype][1]:
        for nested in _nested_types(desc):
            ensure_type(store, nested)


def _nested_types(desc: tuple[Any, Any]) -> Iterator[str]:
    """Yield the message type names a rosbags field description refers to."""
    kind, detail = desc
    if kind == Nodetype.NAME:
        yield detail
    elif kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
        yield from _nested_types(detail[0])



# --- QoS -----------------------------------------------------------------------------------------

def make_qos(*, reliable: bool = True, transient_local: bool = False, depth: int = 100) -> Qos:
    """
    Return the rosbags description of a QoS profile, for a bag's ``offered_qos_profiles``.

    Parameters
    ----------
    reliable : bool
        RELIABLE (True) or BEST_EFFORT (False).
    transient_local : bool
        TRANSIENT_LOCAL (latched, True) or VOLATILE (False).
    depth : int
        KEEP_LAST history depth (messages).

    Returns
    -------
    rosbags.interfaces.Qos
        The profile.

    """
    return Qos(
        history=QosHistory.KEEP_LAST, depth=int(depth),
        reliability=QosReliability.RELIABLE if reliable else QosReliability.BEST_EFFORT,
        durability=QosDurability.TRANSIENT_LOCAL if transient_local else QosDurability.VOLATILE,
        deadline=_NO_DURATION, lifespan=_NO_DURATION, liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=_NO_DURATION, avoid_ros_namespace_conventions=False)


def qos_fields(profiles: Sequence[Qos]) -> tuple[bool, bool, int] | None:
    """
    Summarise a topic's offered QoS profiles as (reliable, transient_local, depth).

    Parameters
    ----------
    profiles : sequence of rosbags.interfaces.Qos
        Profiles offered by the topic's publishers (empty: unknown).

    Returns
    -------
    tuple[bool, bool, int] or None
        RELIABLE if every publisher was reliable, TRANSIENT_LOCAL if every publisher was,
        the largest depth; None for no profiles.

    """
    if not profiles:
        return None
    reliable = all(p.reliability != QosReliability.BEST_EFFORT for p in profiles)
    latched = all(p.durability == QosDurability.TRANSIENT_LOCAL for p in profiles)
    depth = max((p.depth for p in profiles), default=0)
    return reliable, latched, depth
