"""The PyBullet world: arms match their DH chains, the needle body, the table, the placement."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from sim_bridge.bullet import bullet_client, pybullet
from sim_bridge.common.geometry import invert_transform
from sim_bridge.common.needle import NeedleGeometry, ThreadGeometry
from sim_bridge.kinematics import ecm_kinematics, psm_kinematics
from sim_bridge.scene.phantom import PhantomConfig, build_phantom
from sim_bridge.scene.world import World, read_world_config


@pytest.fixture(scope='module')
def kinematics():
    return {'PSM1': psm_kinematics(), 'PSM2': psm_kinematics(), 'ECM': ecm_kinematics()}


@pytest.fixture(scope='module')
def world(kinematics):
    client = bullet_client.BulletClient(connection_mode=pybullet.DIRECT)
    w = World(read_world_config(), kinematics, build_phantom(PhantomConfig()), NeedleGeometry(),
              ThreadGeometry(), client)
    yield w
    client.disconnect()


def test_pybullet_tool_tip_equals_dh_fk_and_shaft_passes_through_rcm(world, kinematics):
    rng = np.random.default_rng(7)
    for name, chain in kinematics.items():
        q = chain.home.copy()
        for _ in range(150):
            # a random walk through the joint space, like a moving arm
            q = np.clip(q + rng.normal(0.0, 0.15, chain.n_joints) * (chain.upper - chain.lower),
                        chain.lower, chain.upper)
            world.set_arm_joints(name, q, jaw=rng.uniform(-0.3, 1.2))
            T_fk = world.T_world_base[name] @ chain.fk(q)
            T_pb = world.tool_tip_pose(name)
            assert np.linalg.norm(T_pb[:3, 3] - T_fk[:3, 3]) < 1e-6
            assert np.abs(T_pb[:3, :3] - T_fk[:3, :3]).max() < 1e-6
            roll = world.link_poses(name)[world.link_index[name]['roll']]
            rcm = world.T_world_base[name][:3, 3]
            off_axis = np.cross(rcm - roll[:3, 3], roll[:3, 2])
            assert np.linalg.norm(off_axis) < 1e-6


def test_every_dh_link_frame_matches_the_chain(world, kinematics):
    chain = kinematics['PSM1']
    q = np.array([0.3, -0.4, 0.15, 1.0, 0.5, -0.6])
    world.set_arm_joints('PSM1', q, jaw=0.4)
    links = world.link_poses('PSM1')
    frames = world.T_world_base['PSM1'] @ chain.fk_links(q)
    for i in range(chain.n_joints):
        assert np.allclose(links[i], frames[i + 1], atol=1e-6)


def test_jaws_open_symmetrically_about_the_tool_x_axis(world):
    for jaw in (0.0, 0.35, 1.0):
        world.set_arm_joints('PSM2', psm_kinematics().home, jaw=jaw)
        links = world.link_poses('PSM2')
        idx = world.link_index['PSM2']
        tip, a, b = links[idx['tip']], links[idx['jaw_a']], links[idx['jaw_b']]
        opening = np.arccos(np.clip(a[:3, 2] @ b[:3, 2], -1.0, 1.0))
        assert opening == pytest.approx(jaw, abs=1e-6)
        half_a = np.arccos(np.clip(a[:3, 2] @ tip[:3, 2], -1.0, 1.0))
        assert half_a == pytest.approx(0.5 * jaw, abs=1e-6)
        assert abs(a[:3, 2] @ tip[:3, 0]) < 1e-6
        assert np.allclose(a[:3, 3], tip[:3, 3], atol=1e-6)


def test_needle_pose_round_trips_through_its_centre_of_mass_frame(world):
    rng = np.random.default_rng(3)
    for _ in range(20):
        T = np.eye(4)
        T[:3, :3] = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
        T[:3, 3] = rng.uniform(-0.05, 0.05, 3)
        world.set_needle_pose(T)
        assert np.allclose(world.needle_pose(), T, atol=1e-9)


def _settle(world, T_start, seconds=1.5):
    world.set_needle_pose(T_start)
    world.set_needle_collisions(True)
    for _ in range(int(seconds / world.config.physics_step)):
        world.step()
    world.set_needle_collisions(False)
    return world.needle_pose()


def test_a_free_needle_falls_and_rests_on_the_pad(world):
    g = world.needle
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler('xyz', [0.3, -0.2, 1.0]).as_matrix()
    T[:3, 3] = [0.004, -0.006, 0.02]
    rest = _settle(world, T)
    linear, angular = world.needle_speed()
    assert linear < 1e-3 and angular < 0.1
    wire = g.points_world(rest, 64)
    top = world.phantom.height(world.phantom.to_phantom(wire)[:, :2])
    clearance = wire[:, 2] - top
    r = 0.5 * g.wire_diameter
    # lying on the pad: the lowest wire point touches the surface, none sinks into it
    assert clearance.min() == pytest.approx(r, abs=3e-4)
    assert np.all(clearance > r - 3e-4)


def test_a_needle_dropped_beside_the_pad_rests_on_the_table(world):
    T = np.eye(4)
    T[:3, 3] = [0.0, 0.08, world.table_height + 0.02]
    rest = _settle(world, T)
    wire = world.needle.points_world(rest, 64)
    assert wire[:, 2].min() == pytest.approx(world.table_height
                                             + 0.5 * world.needle.wire_diameter, abs=3e-4)


def test_support_height_is_the_pad_top_on_the_pad_and_the_table_beside_it(world):
    xy = np.array([[0.0, 0.0], [0.02, -0.01], [0.0, 0.1], [0.2, 0.0]])
    h = world.support_height(xy)
    assert h[0] == pytest.approx(0.0, abs=1e-9)
    assert h[1] == pytest.approx(0.0, abs=1e-9)
    assert h[2] == pytest.approx(world.table_height)
    assert h[3] == pytest.approx(world.table_height)


def _drive_poses(pair, needle, betas):
    """Needle poses of a drive from entry to exit: the arc centre above the pair midpoint."""
    F = pair.frame
    yp, zp = F[:3, 1], F[:3, 2]
    half = 0.5 * pair.chord
    centre = pair.midpoint + np.sqrt(needle.radius ** 2 - half ** 2) * zp
    e = pair.entry - centre
    # the needle normal n such that turning about -n moves the tip from entry into the tissue
    n = yp if np.cross(-yp, e) @ -zp > 0.0 else -yp
    tip = needle.tip / np.linalg.norm(needle.tip)
    phi = np.arctan2(tip[1], tip[0])
    poses = []
    for beta in betas:
        a = Rotation.from_rotvec(-n * beta).apply(e / np.linalg.norm(e))
        x = np.cos(phi) * a - np.sin(phi) * np.cross(n, a)
        T = np.eye(4)
        T[:3, :3] = np.column_stack([x, np.cross(n, x), n])
        T[:3, 3] = centre
        poses.append(T)
    return poses


@pytest.mark.parametrize('kind, prefix', [('synthetic', 'synth'), ('scanned', 'scan')])
def test_both_psms_reach_every_marker_pair_through_a_whole_drive(kind, prefix):
    """Placement check: each PSM can drive the needle through every pair, wrist < 60 deg."""
    config = read_world_config()
    chain = psm_kinematics()
    needle = NeedleGeometry()
    phantom = build_phantom(PhantomConfig(kind=kind, marker_prefix=prefix))
    rolls = np.radians(np.arange(-180.0, 180.0, 15.0))
    for arm in ('PSM1', 'PSM2'):
        T_base_world = invert_transform(config.arms[arm].T)
        for pair in phantom.markers.values():
            for T_needle in _drive_poses(pair, needle, np.radians(np.linspace(-10.0, 60.0, 8))):
                for s in (1.0 / 3.0, 0.75):
                    best = np.inf
                    for roll in rolls:
                        T_tool = T_needle @ invert_transform(needle.grasp_transform(s, roll))
                        Q, ok = chain.ik_batch((T_base_world @ T_tool)[None])
                        if ok[0]:
                            best = min(best, np.abs(Q[0, 4:]).max())
                    assert best < np.radians(60.0), (arm, pair.name, s)


def test_the_drape_draws_the_table_as_its_box_did(world):
    """The table's tiled top, built last, gives the images the table's box gave (cheaper)."""
    from sim_bridge.scene.camera import CameraConfig, StereoCamera

    c = world.client
    camera = StereoCamera(CameraConfig(width=160, height=120, vertical_fov=0.8), c)
    centre = world.phantom.T_world_phantom[:3, 3]
    # looking down on the pad from 12 cm, the table all around it
    T_world_tip = np.eye(4)
    T_world_tip[:3, :3] = Rotation.from_euler('x', 180.0, degrees=True).as_matrix()
    T_world_tip[:3, 3] = centre + [0.0, 0.0, 0.12]
    drawn = camera.render(T_world_tip)
    cfg = world.config
    half = [0.5 * cfg.table_size[0], 0.5 * cfg.table_size[1], 0.0005]
    box = c.createMultiBody(0.0, -1, c.createVisualShape(
        pybullet.GEOM_BOX, halfExtents=half, rgbaColor=list(cfg.table_rgba),
        visualFramePosition=[0.0, 0.0, -0.0005]), [float(centre[0]), float(centre[1]),
                                                  world.table_height])
    place = c.getBasePositionAndOrientation(world.drape_body)
    c.resetBasePositionAndOrientation(world.drape_body, [10.0, 10.0, 10.0], [0, 0, 0, 1])
    try:
        boxed = camera.render(T_world_tip)
    finally:
        c.removeBody(box)
        c.resetBasePositionAndOrientation(world.drape_body, *place)
    assert world.drape_body == c.getBodyUniqueId(c.getNumBodies() - 1)
    table = np.abs(drawn.left_rgb.astype(int) - np.array(cfg.table_rgba[:3]) * 255).max(axis=2)
    assert (table <= 30).mean() > 0.2  # the table is in view
    assert np.array_equal(drawn.left_rgb, boxed.left_rgb)
    assert np.array_equal(drawn.right_rgb, boxed.right_rgb)
