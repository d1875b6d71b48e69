"""
The arms' URDF models: pinocchio and urdfdom's ``check_urdf`` read them, and their forward
kinematics are the simulator's (the DH chains that make ``measured_cp``, and the PyBullet bodies).
"""

import math
import os
from pathlib import Path
import shutil
import subprocess
import sys
from xml.etree import ElementTree as ET

import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial.transform import Rotation
from sim_bridge.kinematics import ecm_kinematics, psm_kinematics
from sim_bridge.robot_model import (
    arm_urdf,
    base_frame,
    is_psm,
    link_name,
    rpy_from_matrix,
    simulation_urdfs,
    simulator_link_frames,
)
from sim_bridge.simulation import Simulation

TOL = 1e-9  # m, and for rotation matrix entries
N_VECTORS = 1000
# (arm, chain factory): the simulator's arms, the Classic instrument and a tilted endoscope
CHAINS = {
    'PSM1': lambda: psm_kinematics(),
    'PSM2-Classic-400006': lambda: psm_kinematics('LARGE_NEEDLE_DRIVER_400006'),
    'ECM': lambda: ecm_kinematics(),
    'ECM-Si-UP': lambda: ecm_kinematics('Si', 'UP'),
}


def rot_x(angle):
    T = np.eye(4)
    T[1:3, 1:3] = [[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]]
    return T


def random_joints(chain, rng, n):
    """``n`` joint vectors (and jaw angles for a PSM) uniform within the limits."""
    Q = rng.uniform(chain.lower, chain.upper, size=(n, chain.n_joints))
    jaws = rng.uniform(chain.jaw_lower, chain.jaw_upper, size=n) if is_psm(chain) else [None] * n
    return Q, jaws


def pin_configuration(model, chain, q, jaw):
    """Pinocchio's q from the arm's joint values, joint by joint name (mimic joints follow)."""
    values = dict(zip(chain.joint_names, q))
    if jaw is not None:
        values['jaw'] = jaw
    qp = np.zeros(model.nq)
    for j in range(1, model.njoints):
        if model.joints[j].nq:
            qp[model.joints[j].idx_q] = values[model.names[j]]
    return qp


def expected_frames(arm, chain, q, jaw):
    """Every URDF link frame in ``<ARM>_base`` as the simulator's DH chain gives it."""
    frames = chain.fk_links(q)
    out = {link_name(arm, name): frames[i + 1] for i, name in enumerate(chain.joint_names)}
    tip = chain.fk(q)
    out[link_name(arm, 'tool_tip')] = tip
    if jaw is not None:
        # the simulator turns its jaw links by -+jaw/2 about tool x (jaw_b, jaw_a); the URDF's
        # jaw links hang on the wrist-yaw link, rotated back by the tooltip offset's rotation
        back = np.eye(4)
        back[:3, :3] = chain.tooltip_offset[:3, :3].T
        out[link_name(arm, 'jaw')] = tip @ rot_x(-jaw) @ back
        out[link_name(arm, 'jaw_1')] = tip @ rot_x(-0.5 * jaw) @ back
        out[link_name(arm, 'jaw_2')] = tip @ rot_x(0.5 * jaw) @ back
    out[base_frame(arm)] = np.eye(4)
    return out


def worst_mismatch(urdf, arm, chain, Q, jaws):
    """Largest position (m) and rotation-entry difference between pinocchio and the chain."""
    model = pin.buildModelFromXML(urdf, mimic=True)
    data = model.createData()
    worst_p = worst_r = 0.0
    for q, jaw in zip(Q, jaws):
        pin.framesForwardKinematics(model, data, pin_configuration(model, chain, q, jaw))
        for name, T in expected_frames(arm, chain, q, jaw).items():
            got = data.oMf[model.getFrameId(name)].homogeneous
            worst_p = max(worst_p, float(np.abs(got[:3, 3] - T[:3, 3]).max()))
            worst_r = max(worst_r, float(np.abs(got[:3, :3] - T[:3, :3]).max()))
    return worst_p, worst_r


def check_urdf_program():
    """urdfdom's check_urdf: installed with pinocchio (cmeel-urdfdom) in the environment."""
    found = shutil.which('check_urdf') or Path(sys.prefix, 'bin', 'check_urdf')
    return str(found) if Path(found).exists() else None


@pytest.mark.parametrize('key', list(CHAINS))
def test_pinocchio_forward_kinematics_equal_the_simulators_at_1000_joint_vectors(key):
    chain = CHAINS[key]()
    arm = key.split('-')[0]
    Q, jaws = random_joints(chain, np.random.default_rng(22), N_VECTORS)
    worst_p, worst_r = worst_mismatch(arm_urdf(arm, chain), arm, chain, Q, jaws)
    assert worst_p < TOL and worst_r < TOL, (worst_p, worst_r)


def test_an_origin_off_by_a_micrometre_is_caught():
    chain = psm_kinematics()
    urdf = arm_urdf('PSM1', chain)
    assert urdf.count('xyz="0 0 0.467"') == 1  # the roll joint: the instrument's shaft length
    Q, jaws = random_joints(chain, np.random.default_rng(1), 10)
    worst_p, _ = worst_mismatch(urdf.replace('xyz="0 0 0.467"', 'xyz="0 0 0.467001"'),
                                'PSM1', chain, Q, jaws)
    assert worst_p > 0.9e-6


def test_the_urdf_links_are_the_simulators_pybullet_links():
    sim = Simulation(rng=np.random.default_rng(0))
    try:
        for arm in ('PSM1', 'PSM2', 'ECM'):
            chain = sim.kinematics[arm]
            model = pin.buildModelFromXML(
                arm_urdf(arm, chain, sim.config.world.instrument, parent='world',
                         T_parent_base=sim.T_world_base(arm)), mimic=True)
            data = model.createData()
            links = simulator_link_frames(arm, chain)
            assert set(links) == set(sim.world.link_index[arm])
            Q, jaws = random_joints(chain, np.random.default_rng(2), 200)
            for q, jaw in zip(Q, jaws):
                sim.world.set_arm_joints(arm, q, jaw)
                poses = sim.world.link_poses(arm)
                pin.framesForwardKinematics(model, data, pin_configuration(model, chain, q, jaw))
                for sim_name, (urdf_name, T_link_sim) in links.items():
                    got = data.oMf[model.getFrameId(urdf_name)].homogeneous @ T_link_sim
                    want = poses[sim.world.link_index[arm][sim_name]]
                    # PyBullet keeps link poses to about 3e-8 m and 5e-7 in rotation
                    # (the DH chain itself differs from it by as much)
                    assert np.abs(got[:3, 3] - want[:3, 3]).max() < 1e-7, (arm, sim_name)
                    assert np.abs(got[:3, :3] - want[:3, :3]).max() < 2e-6, (arm, sim_name)
    finally:
        sim.close()


@pytest.mark.parametrize('key', list(CHAINS))
def test_joint_and_link_names_are_the_dvrks(key):
    chain = CHAINS[key]()
    arm = key.split('-')[0]
    robot = ET.fromstring(arm_urdf(arm, chain))
    joints = {j.get('name'): j for j in robot.findall('joint')}
    moving = [n for n, j in joints.items() if j.get('type') != 'fixed' and j.find('mimic') is None]
    # measured_js names, then jaw/measured_js's
    assert moving == list(chain.joint_names) + (['jaw'] if is_psm(chain) else [])
    links = [link.get('name') for link in robot.findall('link')]
    assert links[0] == f'{arm}_base' and all(n.startswith(f'{arm}_') for n in links)
    if is_psm(chain):
        mimic = {n: (j.find('mimic').get('joint'), float(j.find('mimic').get('multiplier')))
                 for n, j in joints.items() if j.find('mimic') is not None}
        assert mimic == {'jaw_1': ('jaw', 0.5), 'jaw_2': ('jaw', -0.5)}
        assert {joints[n].find('parent').get('link') for n in mimic} == {f'{arm}_wrist_yaw_link'}
        limits = joints['jaw'].find('limit')
        assert (float(limits.get('lower')), float(limits.get('upper'))) == (
            chain.jaw_lower, chain.jaw_upper)


@pytest.mark.parametrize('key', list(CHAINS))
def test_check_urdf_accepts_each_model(key, tmp_path):
    program = check_urdf_program()
    if program is None:
        pytest.skip('check_urdf is not installed (it comes with pin through cmeel-urdfdom)')
    arm = key.split('-')[0]
    path = tmp_path / f'{arm}.urdf'
    path.write_text(arm_urdf(arm, CHAINS[key](), parent='world'))
    done = subprocess.run([program, str(path)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stdout + done.stderr
    assert 'Successfully Parsed XML' in done.stdout
    assert 'root Link: world' in done.stdout


def test_check_urdf_rejects_a_broken_model(tmp_path):
    program = check_urdf_program()
    if program is None:
        pytest.skip('check_urdf is not installed (it comes with pin through cmeel-urdfdom)')
    path = tmp_path / 'broken.urdf'
    path.write_text(arm_urdf('PSM1', psm_kinematics()).replace(
        '<parent link="PSM1_roll_link" />', '<parent link="PSM1_nowhere_link" />'))
    done = subprocess.run([program, str(path)], capture_output=True, text=True, timeout=60)
    assert done.returncode != 0


def test_the_jaw_halves_turn_about_the_wrist_yaw_axis_as_dvrk_models_do():
    # dvrk_model (tip_006): jaw_1 / jaw_2 turn by +jaw/2 / -jaw/2 about the wrist-yaw link's z
    chain = psm_kinematics()
    model = pin.buildModelFromXML(arm_urdf('PSM1', chain), mimic=True)
    data = model.createData()
    Q, jaws = random_joints(chain, np.random.default_rng(3), 100)
    for q, jaw in zip(Q, jaws):
        pin.framesForwardKinematics(model, data, pin_configuration(model, chain, q, jaw))
        wrist = chain.fk_links(q)[-1]
        for name, angle in (('jaw_1', 0.5 * jaw), ('jaw_2', -0.5 * jaw)):
            want = wrist.copy()
            want[:3, :3] = wrist[:3, :3] @ Rotation.from_rotvec([0.0, 0.0, angle]).as_matrix()
            got = data.oMf[model.getFrameId(f'PSM1_{name}_link')].homogeneous
            assert np.abs(got - want).max() < TOL


def test_a_parent_frame_places_the_base():
    chain = ecm_kinematics()
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler('xyz', [0.6435011087932844, 0.1, -0.2]).as_matrix()
    T[:3, 3] = (0.0, -0.12, 0.17)
    model = pin.buildModelFromXML(arm_urdf('ECM', chain, parent='world', T_parent_base=T))
    data = model.createData()
    q = np.array([0.3, -0.2, 0.1, 0.5])
    pin.framesForwardKinematics(model, data, pin_configuration(model, chain, q, None))
    got = data.oMf[model.getFrameId('ECM_tool_tip_link')].homogeneous
    assert np.abs(got - T @ chain.fk(q)).max() < TOL


def test_rpy_rebuilds_every_rotation_also_at_gimbal_lock():
    rng = np.random.default_rng(5)
    rotations = list(Rotation.random(2000, random_state=rng).as_matrix())
    for pitch in (math.pi / 2, -math.pi / 2, math.pi / 2 - 1e-9, -math.pi / 2 + 1e-12):
        for yaw, roll in rng.uniform(-math.pi, math.pi, size=(50, 2)):
            rotations.append(Rotation.from_euler('ZYX', [yaw, pitch, roll]).as_matrix())
    for R in rotations:
        roll, pitch, yaw = rpy_from_matrix(R)
        rebuilt = Rotation.from_euler('ZYX', [yaw, pitch, roll]).as_matrix()
        assert np.abs(rebuilt - R).max() < 1e-14


def test_a_bad_arm_name_is_refused():
    with pytest.raises(ValueError, match='arm name'):
        arm_urdf('PSM1/../x', psm_kinematics())
    with pytest.raises(ValueError, match='needs parent'):
        arm_urdf('PSM1', psm_kinematics(), T_parent_base=np.eye(4))


def test_the_command_line_writes_the_models_the_simulator_uses(tmp_path):
    env = dict(os.environ)
    out = tmp_path / 'psm2.urdf'
    cli = [str(Path(sys.prefix, 'bin', 'suture-lfd'))]
    done = subprocess.run([*cli, 'urdf', '--arm', 'PSM2', '--out', str(out)],
                          capture_output=True, text=True, timeout=120, env=env)
    assert done.returncode == 0, done.stderr
    sim = Simulation(rng=np.random.default_rng(0))
    try:
        shape = sim.config.world.instrument
        assert out.read_text() == arm_urdf('PSM2', sim.kinematics['PSM2'], shape)
        done = subprocess.run([*cli, 'urdf', '--arm', 'ECM', '--parent', 'world'],
                              capture_output=True, text=True, timeout=120, env=env)
        assert done.returncode == 0, done.stderr
        assert done.stdout == arm_urdf('ECM', sim.kinematics['ECM'], shape, parent='world',
                                       T_parent_base=sim.T_world_base('ECM'))
    finally:
        sim.close()
    done = subprocess.run([*cli, 'urdf', '--arm', 'all', '--out', str(tmp_path / 'models')],
                          capture_output=True, text=True, timeout=120, env=env)
    assert done.returncode == 0, done.stderr
    assert {p.name: p.read_text() for p in (tmp_path / 'models').iterdir()} == {
        f'{arm}.urdf': text for arm, text in simulation_urdfs().items()}
    for bad, word in ((['--arm', 'PSM3'], 'PSM3'), (['--arm', 'all'], '--out FOLDER')):
        done = subprocess.run([*cli, 'urdf', *bad], capture_output=True, text=True,
                              timeout=120, env=env)
        assert done.returncode == 2 and word in done.stderr, done.stderr
