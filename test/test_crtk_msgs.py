"""
crtk_msgs in the environment is collaborative-robotics/crtk_msgs 1.3.0, field for field.

The table below is taken from the upstream ``msg/`` and ``srv/`` files of release 1.3.0 (rosidl
type names: ``float64[]`` is ``sequence<double>``, ``T[6]`` is ``T[6]``). A dVRK Python client
(``crtk`` and ``dvrk`` packages) imports these names at import time, used or not.
"""

import importlib

import pytest

UPSTREAM_MESSAGES = {
    'OperatingState': [
        ('header', 'std_msgs/Header'), ('state', 'string'), ('is_homed', 'boolean'),
        ('is_busy', 'boolean')],
    'StringStamped': [('header', 'std_msgs/Header'), ('string', 'string')],
    'CartesianImpedanceHalfPlaneGains': [
        ('p', 'geometry_msgs/Vector3'), ('d', 'geometry_msgs/Vector3'),
        ('bias', 'geometry_msgs/Vector3'), ('deadband', 'geometry_msgs/Vector3')],
    'CartesianImpedance': [
        ('header', 'std_msgs/Header'), ('force_orientation', 'geometry_msgs/Quaternion'),
        ('force_position', 'geometry_msgs/Vector3'),
        ('torque_orientation', 'geometry_msgs/Quaternion'),
        ('position_positive', 'crtk_msgs/CartesianImpedanceHalfPlaneGains'),
        ('position_negative', 'crtk_msgs/CartesianImpedanceHalfPlaneGains'),
        ('orientation_positive', 'crtk_msgs/CartesianImpedanceHalfPlaneGains'),
        ('orientation_negative', 'crtk_msgs/CartesianImpedanceHalfPlaneGains')],
    'CartesianState': [
        ('header', 'std_msgs/Header'), ('pose', 'geometry_msgs/Pose'),
        ('pose_is_valid', 'std_msgs/Bool'), ('twist', 'geometry_msgs/Twist'),
        ('twist_is_valid', 'std_msgs/Bool'), ('wrench', 'geometry_msgs/Wrench'),
        ('wrench_is_valid', 'std_msgs/Bool')],
    'SetpointMode': [('value', 'uint8')],
    'JointServo': [
        ('header', 'std_msgs/Header'), ('name', 'sequence<string>'),
        ('position', 'sequence<double>'), ('velocity', 'sequence<double>'),
        ('effort', 'sequence<double>'), ('mode', 'sequence<crtk_msgs/SetpointMode>')],
    'CartesianServo': [
        ('header', 'std_msgs/Header'), ('task_frame', 'geometry_msgs/Transform'),
        ('pose', 'geometry_msgs/Pose'), ('twist', 'geometry_msgs/Twist'),
        ('wrench', 'geometry_msgs/Wrench'), ('axis_mode', 'crtk_msgs/SetpointMode[6]')],
}

UPSTREAM_SERVICES = {
    'TriggerOperatingState': (
        [], [('operating_state', 'crtk_msgs/OperatingState')]),
    'QueryForwardKinematics': (
        [('jp', 'sequence<double>'), ('cp', 'geometry_msgs/Pose')],
        [('cp', 'geometry_msgs/Pose'), ('result', 'boolean'), ('message', 'string')]),
    'QueryInverseKinematics': (
        [('cp', 'geometry_msgs/Pose'), ('jp', 'sequence<double>')],
        [('jp', 'sequence<double>'), ('result', 'boolean'), ('message', 'string')]),
}

SETPOINT_MODE_CONSTANTS = {'POSITION': 1, 'VELOCITY': 2, 'EFFORT': 4, 'NONE': 0, 'P': 1, 'V': 2,
                           'PV': 3, 'F': 4, 'PF': 5, 'VF': 6, 'PVF': 7}

# what the dVRK Python client imports from crtk_msgs (crtk utils, dvrk arm/mtm and scripts)
CLIENT_IMPORTS = {
    'crtk_msgs.msg': ('OperatingState', 'StringStamped', 'CartesianImpedance',
                      'CartesianImpedanceHalfPlaneGains', 'CartesianState', 'CartesianServo',
                      'JointServo', 'SetpointMode'),
    'crtk_msgs.srv': ('TriggerOperatingState', 'QueryForwardKinematics',
                      'QueryInverseKinematics'),
}


def _fields(cls):
    return list(cls.get_fields_and_field_types().items())


@pytest.mark.parametrize('name', sorted(UPSTREAM_MESSAGES))
def test_message_fields_match_upstream(name):
    msg = importlib.import_module('crtk_msgs.msg')
    assert _fields(getattr(msg, name)) == UPSTREAM_MESSAGES[name]


@pytest.mark.parametrize('name', sorted(UPSTREAM_SERVICES))
def test_service_fields_match_upstream(name):
    srv = getattr(importlib.import_module('crtk_msgs.srv'), name)
    request, response = UPSTREAM_SERVICES[name]
    assert _fields(srv.Request) == request
    assert _fields(srv.Response) == response


def test_setpoint_mode_constants_match_upstream():
    from crtk_msgs.msg import SetpointMode
    assert {k: getattr(SetpointMode, k) for k in SETPOINT_MODE_CONSTANTS} == \
        SETPOINT_MODE_CONSTANTS


def test_the_package_has_no_other_interfaces():
    for module, names in (('crtk_msgs.msg', UPSTREAM_MESSAGES),
                          ('crtk_msgs.srv', UPSTREAM_SERVICES)):
        mod = importlib.import_module(module)
        # a service also has its generated _Request, _Response and _Event types
        public = {n for n in dir(mod) if n[:1].isupper() and '_' not in n}
        assert public == set(names), module


def test_every_name_a_dvrk_client_imports_is_there():
    for module, names in CLIENT_IMPORTS.items():
        mod = importlib.import_module(module)
        for name in names:
            cls = getattr(mod, name)
            cls() if module.endswith('msg') else (cls.Request(), cls.Response())


def test_cartesian_servo_has_six_axis_modes_and_round_trips():
    from crtk_msgs.msg import CartesianServo, SetpointMode
    from rclpy.serialization import deserialize_message, serialize_message
    msg = CartesianServo()
    assert len(msg.axis_mode) == 6
    msg.axis_mode[2] = SetpointMode(value=SetpointMode.PV)
    msg.pose.position.x = 0.25
    back = deserialize_message(serialize_message(msg), CartesianServo)
    assert back.axis_mode[2].value == SetpointMode.PV and back.pose.position.x == 0.25
