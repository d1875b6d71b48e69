"""
dVRK kinematics: modified-DH chains, closed-form RCM inverse kinematics, and the dVRK's numbers.

- :mod:`~sim_bridge.kinematics.dh_chain`: modified-DH serial chains (forward kinematics,
  Jacobians, pose checks).
- :mod:`~sim_bridge.kinematics.rcm`: the PSM's and ECM's closed-form inverse kinematics around
  the remote centre of motion.
- :mod:`~sim_bridge.kinematics.dvrk`: ``config/kinematics.yaml`` read into the chains
  (:func:`psm_kinematics`, :func:`ecm_kinematics`, :func:`load_kinematics`).

Units are SI (metres, radians); the tool-tip pose is ``T_base_tip`` in the RCM frame
``<ARM>_base``.
"""

from sim_bridge.kinematics.dh_chain import (
    DhJoint,
    SerialChain,
    check_joint_vector,
    check_pose,
    check_poses,
    pinocchio_model,
    rotation_angle,
)
from sim_bridge.kinematics.dvrk import (
    ArmChainConfig,
    KinematicsConfig,
    KinematicsDefaults,
    PsmToolConfig,
    ecm_kinematics,
    load_kinematics,
    psm_kinematics,
    read_kinematics_config,
)
from sim_bridge.kinematics.rcm import (
    IK_TOLERANCE,
    EcmKinematics,
    JawLimits,
    PsmKinematics,
    UnreachableError,
)

__all__ = [
    'ArmChainConfig', 'check_joint_vector', 'check_pose', 'check_poses', 'DhJoint',
    'EcmKinematics', 'ecm_kinematics', 'IK_TOLERANCE', 'JawLimits', 'KinematicsConfig',
    'KinematicsDefaults', 'load_kinematics', 'pinocchio_model', 'psm_kinematics',
    'PsmKinematics', 'PsmToolConfig', 'read_kinematics_config', 'rotation_angle', 'SerialChain',
    'UnreachableError',
]
