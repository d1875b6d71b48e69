"""The dVRK chains match the reference numbers, IK inverts FK, Jacobians agree three ways."""

import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial.transform import Rotation
from sim_bridge.common.configfile import ConfigError
from sim_bridge.kinematics import (
    EcmKinematics,
    PsmKinematics,
    UnreachableError,
    check_pose,
    ecm_kinematics,
    load_kinematics,
    pinocchio_model,
    psm_kinematics,
    rotation_angle,
)

DEG = np.pi / 180.0
PSM_HOME = [0.0, 0.0, 0.12, 0.0, 0.0, 0.0]
ISI_TIP_ROTATION = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


@pytest.fixture(scope='module')
def psm():
    return psm_kinematics()


@pytest.fixture(scope='module')
def psm_classic():
    return psm_kinematics('LARGE_NEEDLE_DRIVER_400006')


@pytest.fixture(scope='module')
def ecm():
    return ecm_kinematics()


def random_q(chain, rng, m):
    return rng.uniform(chain.lower, chain.upper, size=(m, chain.n_joints))


# --- the numbers of the reference -----------------------------------------------------------


def test_psm_home_puts_the_tip_113_5_mm_below_the_rcm(psm):
    T = psm.fk(PSM_HOME)
    np.testing.assert_allclose(T[:3, 3], [0.0, 0.0, -0.1135], atol=1e-12)
    np.testing.assert_allclose(T[:3, :3], ISI_TIP_ROTATION, atol=1e-12)


def test_psm_at_zero_has_the_tip_6_5_mm_above_the_rcm(psm):
    np.testing.assert_allclose(psm.fk(np.zeros(6))[:3, 3], [0.0, 0.0, 0.0065], atol=1e-12)


def test_psm_joint_directions_follow_the_dvrk(psm):
    home = psm.fk(PSM_HOME)[:3, 3]
    assert psm.fk([0.1, 0, 0.12, 0, 0, 0])[0, 3] > home[0] + 0.01  # +yaw -> +X
    assert psm.fk([0, 0.1, 0.12, 0, 0, 0])[1, 3] < home[1] - 0.01  # +pitch -> -Y
    assert psm.fk([0, 0, 0.15, 0, 0, 0])[2, 3] == pytest.approx(home[2] - 0.03)  # insertion -Z
    np.testing.assert_allclose(psm.fk([0, 0, 0.12, 0, 0, 0.7])[:3, 3], home, atol=1e-12)


def test_classic_400006_and_si_420006_have_identical_forward_kinematics(psm, psm_classic):
    rng = np.random.default_rng(1)
    Q = random_q(psm_classic, rng, 500)  # Classic limits lie inside the Si limits
    np.testing.assert_allclose(psm.fk_batch(Q), psm_classic.fk_batch(Q), atol=1e-12)
    shaft = psm.joints[2].offset + psm.joints[3].d
    shaft_classic = psm_classic.joints[2].offset + psm_classic.joints[3].d
    assert shaft == pytest.approx(-0.0156) and shaft_classic == pytest.approx(-0.0156)


def test_psm_joint_names_limits_and_speeds_are_the_dvrk_values(psm, psm_classic):
    assert psm.joint_names == ('yaw', 'pitch', 'insertion', 'roll', 'wrist_pitch', 'wrist_yaw')
    np.testing.assert_allclose(psm.lower, [-2.964, -1.265, 0.0, -4.53786, -1.39626, -1.39626])
    np.testing.assert_allclose(psm.upper, [2.964, 1.301, 0.29, 4.53786, 1.39626, 1.39626])
    np.testing.assert_allclose(psm_classic.lower[:3], [-1.588, -0.925025, 0.0])
    np.testing.assert_allclose(psm_classic.upper[:3], [1.588, 0.925025, 0.24])
    np.testing.assert_allclose(psm.v_max, [90 * DEG, 90 * DEG, 0.2] + [1080 * DEG] * 3)
    np.testing.assert_allclose(psm.a_max, [90 * DEG, 90 * DEG, 0.2] + [720 * DEG] * 3)
    assert (psm.jaw_lower, psm.jaw_upper) == (-0.349066, 1.39626)
    assert (psm_classic.jaw_lower, psm_classic.jaw_upper) == (-0.698132, 1.39626)
    assert psm.jaw_v_max == pytest.approx(1080 * DEG)
    assert psm.jaw_a_max == pytest.approx(720 * DEG)
    assert psm.tool_type == 'LARGE_NEEDLE_DRIVER:420006[1]'


def test_ecm_home_looks_down_the_insertion_axis(ecm):
    T = ecm.fk([0.0, 0.0, 0.12, 0.0])
    np.testing.assert_allclose(T[:3, 3], [0.0, 0.0, -0.1207], atol=1e-12)
    np.testing.assert_allclose(T[:3, :3], np.diag([1.0, -1.0, -1.0]), atol=1e-12)
    assert ecm.joint_names == ('yaw', 'pitch', 'insertion', 'roll')
    np.testing.assert_allclose(ecm.v_max, [30 * DEG, 30 * DEG, 0.06, 30 * DEG])
    np.testing.assert_allclose(ecm.a_max, [90 * DEG, 90 * DEG, 0.06, 90 * DEG])
    assert ecm.endoscope_type == 'Classic_SD_STRAIGHT'


def test_ecm_up_and_down_endoscopes_tilt_the_camera_by_30_degrees(ecm):
    q = [0.0, 0.0, 0.12, 0.0]
    straight = ecm.fk(q)
    for name, sign in (('UP', -1.0), ('DOWN', 1.0)):
        tilted = ecm_kinematics(endoscope=name).fk(q)
        relative = straight[:3, :3].T @ tilted[:3, :3]
        np.testing.assert_allclose(relative, Rotation.from_euler('x', sign * 30 * DEG)
                                   .as_matrix(), atol=1e-12)
        np.testing.assert_allclose(tilted[:3, 3], straight[:3, 3], atol=1e-12)


def test_si_ecm_is_selectable():
    ecm_si = ecm_kinematics('Si')
    assert isinstance(ecm_si, EcmKinematics)
    np.testing.assert_allclose(ecm_si.upper, [2.964, 1.04, 0.259, 1.54])


def test_load_kinematics_builds_the_default_psm_and_ecm():
    chains = load_kinematics()
    assert isinstance(chains['PSM'], PsmKinematics)
    assert chains['PSM'].name == 'PSM Si + LARGE_NEEDLE_DRIVER_420006'
    assert isinstance(chains['ECM'], EcmKinematics)


def test_dvrk_tool_spelling_is_accepted_and_unknown_tools_are_named():
    assert psm_kinematics('LARGE_NEEDLE_DRIVER:400006').name.endswith('400006')
    with pytest.raises(ConfigError, match='unknown PSM tool .*LARGE_NEEDLE_DRIVER_420006'):
        psm_kinematics('SCISSORS')


# --- frames ---------------------------------------------------------------------------------


def test_fk_all_ends_with_the_tip_and_holds_every_link_frame(psm):
    q = np.array([0.3, -0.2, 0.15, 1.0, 0.4, -0.5])
    links = psm.fk_links(q)
    frames = psm.fk_all(q)
    assert frames.shape == (7, 4, 4)
    np.testing.assert_allclose(frames[0], np.eye(4))
    np.testing.assert_allclose(frames[1:6], links[1:6])
    np.testing.assert_allclose(frames[-1], psm.fk(q), atol=1e-15)
    np.testing.assert_allclose(links[-1] @ psm.tooltip_offset, psm.fk(q), atol=1e-15)
    # the roll frame origin sits on the shaft at insertion - 15.6 mm from the RCM
    shaft = links[3][:3, 2]
    np.testing.assert_allclose(links[4][:3, 3], (0.15 - 0.0156) * shaft, atol=1e-12)


def test_fk_batch_equals_fk(psm):
    rng = np.random.default_rng(2)
    Q = random_q(psm, rng, 20)
    np.testing.assert_allclose(psm.fk_batch(Q), np.stack([psm.fk(q) for q in Q]), atol=1e-15)


def test_clip_and_within_limits(psm):
    q = np.array([4.0, 0.0, -0.1, 0.0, 0.0, 2.0])
    assert not psm.within_limits(q)
    clipped = psm.clip(q)
    assert psm.within_limits(clipped)
    np.testing.assert_allclose(clipped, [2.964, 0.0, 0.0, 0.0, 0.0, 1.39626])


# --- inverse kinematics ---------------------------------------------------------------------


def test_ik_inverts_fk_for_10000_random_joint_vectors(psm):
    """Whole joint ranges, insertion 0..0.29 m (singular points are not hit by chance)."""
    rng = np.random.default_rng(3)
    Q = random_q(psm, rng, 10_000)
    T = psm.fk_batch(Q)
    Q_ik, reachable = psm.ik_batch(T, q_ref=Q)
    assert reachable.all()
    assert np.max(np.abs(Q_ik - Q)) < 1e-6
    # without the hint IK may pick another branch (roll +-2 pi, flipped wrist) but the same pose
    Q_any, reachable = psm.ik_batch(T)
    assert reachable.all()
    T_any = psm.fk_batch(Q_any)
    assert np.max(np.linalg.norm(T_any[:, :3, 3] - T[:, :3, 3], axis=1)) < 1e-6
    assert np.max(rotation_angle(T_any[:, :3, :3], T[:, :3, :3])) < 1e-6
    assert psm.within_limits(Q_any).all()


def test_scalar_ik_matches_batch_ik(psm, psm_classic, ecm):
    rng = np.random.default_rng(4)
    for chain in (psm, psm_classic, ecm):
        Q = random_q(chain, rng, 50)
        T = chain.fk_batch(Q)
        Q_batch, _ = chain.ik_batch(T, Q)
        for q, t, qb in zip(Q, T, Q_batch):
            np.testing.assert_allclose(chain.ik(t, q_ref=q), qb, atol=1e-12)
            np.testing.assert_allclose(qb, q, atol=1e-6)


def test_one_pose_ik_picks_the_batch_solution_for_any_reference(psm, psm_classic):
    """The plain-float path for one pose chooses the same branch and wrap as the batch solver."""
    rng = np.random.default_rng(11)
    for chain in (psm, psm_classic):
        Q = random_q(chain, rng, 2000)
        T = chain.fk_batch(Q)
        # references: far (random in the limits) and near (a streaming servo_cp step away)
        refs = np.concatenate((random_q(chain, rng, 1000),
                               Q[1000:] + rng.normal(0.0, 0.05, (1000, chain.n_joints))))
        Q_batch, ok = chain.ik_batch(T, refs)
        fast = 0
        for t, ref, qb, good in zip(T, refs, Q_batch, ok):
            q = chain._single.solve(t, ref)
            if q is None:
                continue  # the batch solver decides these
            fast += 1
            assert good
            np.testing.assert_allclose(q, qb, atol=1e-9)
            np.testing.assert_allclose(chain.ik(t, q_ref=ref), qb, atol=1e-9)
        assert fast >= 1900


def test_the_unchecked_paths_give_the_checked_answers_bit_for_bit(psm, ecm):
    """What an arm calls on its own (already checked) joints and goals is fk / ik, unchecked."""
    rng = np.random.default_rng(12)
    for chain in (psm, ecm):
        for q in random_q(chain, rng, 200):
            shared = chain.fk_unchecked(tuple(q.tolist()), read_only=True)
            assert not shared.flags.writeable
            assert shared.tobytes() == chain.fk(q).tobytes()
            assert chain.fk_unchecked(q.tolist()).tobytes() == chain.fk(q).tobytes()
    Q = random_q(psm, rng, 300)
    refs = Q + rng.normal(0.0, 0.05, Q.shape)
    refs[::3] = random_q(psm, rng, 100)  # far references too
    for q, ref in zip(Q, np.clip(refs, psm.lower, psm.upper)):
        T = psm.fk(q)
        unchecked = psm.ik_unchecked(T, tuple(ref.tolist()))
        assert np.array(unchecked).tobytes() == psm.ik(T, q_ref=ref).tobytes()
    outside = psm.fk(np.array([0.1, 0.2, 0.1, 0.2, 0.1, 0.1]))
    outside[:3, 3] *= 10.0  # far beyond the insertion range
    with pytest.raises(UnreachableError, match='joint limits'):
        psm.ik_unchecked(outside, tuple(psm.home.tolist()))


def test_ik_wraps_roll_towards_the_reference(psm):
    q = np.array([0.1, 0.2, 0.1, 2.5, 0.3, 0.2])
    T = psm.fk(q)
    np.testing.assert_allclose(psm.ik(T, q_ref=q), q, atol=1e-9)
    wrapped = psm.ik(T, q_ref=[0.1, 0.2, 0.1, -3.5, 0.3, 0.2])
    assert wrapped[3] == pytest.approx(2.5 - 2 * np.pi)
    np.testing.assert_allclose(psm.fk(wrapped), T, atol=1e-12)


def test_ik_keeps_the_rcm_by_construction(psm):
    """The shaft (the line through the RCM and the roll-frame origin) passes the RCM."""
    rng = np.random.default_rng(5)
    for q in random_q(psm, rng, 100):
        q_ik = psm.ik(psm.fk(q), q_ref=q)
        links = psm.fk_links(q_ik)
        shaft, origin = links[3][:3, 2], links[4][:3, 3]
        assert np.linalg.norm(np.cross(shaft, origin)) < 1e-12


def test_ecm_ik_inverts_fk(ecm):
    rng = np.random.default_rng(6)
    Q = random_q(ecm, rng, 2000)
    Q_ik, reachable = ecm.ik_batch(ecm.fk_batch(Q), Q)
    assert reachable.all()
    assert np.max(np.abs(Q_ik - Q)) < 1e-6


def test_too_deep_a_pose_is_unreachable(psm):
    T = psm.fk(PSM_HOME)
    T[2, 3] = -0.5
    with pytest.raises(UnreachableError, match=r'outside the joint limits.*insertion = 0\.50'):
        psm.ik(T)
    Q, reachable = psm.ik_batch(np.stack([T, psm.fk(PSM_HOME)]))
    assert reachable.tolist() == [False, True]
    assert np.isnan(Q[0]).all() and np.isfinite(Q[1]).all()


def test_a_pose_beyond_the_pitch_limit_is_unreachable(psm_classic):
    q = [0.0, 1.2, 0.12, 0.0, 0.0, 0.0]  # pitch beyond the Classic +-0.925 rad
    with pytest.raises(UnreachableError, match='pitch'):
        psm_classic.ik(psm_kinematics().fk(q))


def test_ecm_reports_an_orientation_it_cannot_produce(ecm):
    T = ecm.fk([0.1, 0.1, 0.1, 0.1])
    T[:3, :3] = T[:3, :3] @ Rotation.from_rotvec([0.1, 0.0, 0.0]).as_matrix()
    with pytest.raises(UnreachableError, match='camera axis'):
        ecm.ik(T)


def test_the_singular_tip_on_the_yaw_axis_line_is_reported(psm):
    T = np.eye(4)
    T[:3, :3] = ISI_TIP_ROTATION
    T[:3, :3] = Rotation.from_rotvec([0.0, 0.0, 0.3]).as_matrix() @ T[:3, :3]
    R6 = T[:3, :3] @ psm.tooltip_offset[:3, :3].T
    T[:3, 3] = 0.05 * R6[:, 2]  # tip on the wrist-yaw axis line through the RCM
    with pytest.raises(UnreachableError, match='singular'):
        psm.ik(T)


@pytest.mark.parametrize('bad, message', [
    (np.full(6, np.nan), 'NaN'),
    ([0.0, 0.0, np.inf, 0.0, 0.0, 0.0], 'NaN or infinite'),
    ([0.0, 0.0, 0.1], 'must have 6 joint values'),
    ('abc', 'must be 6 numbers'),
])
def test_bad_joint_vectors_are_rejected(psm, bad, message):
    with pytest.raises(ValueError, match=message):
        psm.fk(bad)
    with pytest.raises(ValueError, match=message):
        psm.jacobian(bad)


@pytest.mark.parametrize('bad, message', [
    (np.full((4, 4), np.nan), 'NaN'),
    (np.eye(3), r'shape \(4, 4\)'),
    (np.diag([0.0, 0.0, 0.0, 1.0]), 'not a proper rotation'),
    (np.diag([1.0, 1.0, -1.0, 1.0]), 'det = -1'),
    (np.diag([2.0, 1.0, 1.0, 1.0]), 'not a proper rotation'),
])
def test_bad_poses_are_rejected_before_ik(psm, bad, message):
    with pytest.raises(ValueError, match=message):
        psm.ik(bad)
    with pytest.raises(ValueError, match=message):
        check_pose(bad)


def test_nan_reference_is_rejected(psm):
    with pytest.raises(ValueError, match='q_ref'):
        psm.ik(psm.fk(PSM_HOME), q_ref=[np.nan] * 6)


# --- Jacobians ------------------------------------------------------------------------------


def finite_difference_jacobian(chain, q, h=1e-7):
    T0 = chain.fk(q)
    J = np.zeros((6, chain.n_joints))
    for i in range(chain.n_joints):
        dq = np.zeros(chain.n_joints)
        dq[i] = h
        Tp, Tm = chain.fk(q + dq), chain.fk(q - dq)
        J[:3, i] = (Tp[:3, 3] - Tm[:3, 3]) / (2 * h)
        dR = (Tp[:3, :3] - Tm[:3, :3]) / (2 * h) @ T0[:3, :3].T
        J[3:, i] = [dR[2, 1], dR[0, 2], dR[1, 0]]
    return J


@pytest.mark.parametrize('which', ['psm', 'psm_classic', 'ecm'])
def test_jacobian_equals_pinocchio_and_finite_differences(which, request):
    chain = request.getfixturevalue(which)
    model, tip = pinocchio_model(chain)
    data = model.createData()
    rng = np.random.default_rng(7)
    for q in random_q(chain, rng, 30):
        J = chain.jacobian(q)
        pin.framesForwardKinematics(model, data, q)
        np.testing.assert_allclose(data.oMf[tip].homogeneous, chain.fk(q), atol=1e-12)
        J_pin = pin.computeFrameJacobian(model, data, q, tip, pin.LOCAL_WORLD_ALIGNED)
        np.testing.assert_allclose(J, J_pin, atol=1e-12)
        np.testing.assert_allclose(J, finite_difference_jacobian(chain, q), atol=1e-7)
        J_body = pin.computeFrameJacobian(model, data, q, tip, pin.LOCAL)
        np.testing.assert_allclose(chain.jacobian_body(q), J_body, atol=1e-12)


def test_joint_placements_are_the_link_transforms_at_zero(psm):
    placements = psm.joint_placements()
    np.testing.assert_allclose(psm.fk_links(np.zeros(6))[1:],
                               np.stack([np.linalg.multi_dot([np.eye(4)] + list(placements[:i]))
                                         for i in range(1, 7)]), atol=1e-15)
