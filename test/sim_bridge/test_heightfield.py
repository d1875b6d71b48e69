"""Height fields: bilinear depth queries and the bound of the top surface near a point."""

import numpy as np
from sim_bridge.scene.heightfield import HeightField


def _bumpy(seed=0):
    rng = np.random.default_rng(seed)
    ny, nx = 60, 80
    y, x = np.mgrid[0:ny, 0:nx]
    top = 0.004 * np.sin(x / 7.0) * np.cos(y / 5.0) + 0.001 * rng.random((ny, nx))
    footprint = (x - 40) ** 2 / 40.0 ** 2 + (y - 30) ** 2 / 30.0 ** 2 <= 1.0
    return HeightField(-0.02, -0.015, 0.0005, top, top - 0.01, footprint)


def test_depth_is_the_bilinear_top_minus_z_inside_the_grid():
    hf = _bumpy()
    rng = np.random.default_rng(1)
    xy = rng.uniform([-0.0195, -0.0145], [0.0190, 0.0140], size=(500, 2))
    z = rng.uniform(-0.012, 0.006, size=500)
    depth, inside = hf.depth(np.column_stack([xy, z]))
    fx, fy = (xy[:, 0] - hf.x0) / hf.spacing, (xy[:, 1] - hf.y0) / hf.spacing
    i, j = fx.astype(int), fy.astype(int)
    tx, ty = fx - i, fy - j
    t = hf.top
    top = ((1 - tx) * (1 - ty) * t[j, i] + tx * (1 - ty) * t[j, i + 1]
           + (1 - tx) * ty * t[j + 1, i] + tx * ty * t[j + 1, i + 1])
    corners = np.stack([hf.footprint[j, i], hf.footprint[j, i + 1], hf.footprint[j + 1, i],
                        hf.footprint[j + 1, i + 1]]).all(axis=0)
    assert np.allclose(depth[corners], top[corners] - z[corners], atol=1e-12)
    expected = (z <= top + 1e-12) & (z >= top - 0.01)
    assert np.array_equal(inside[corners], expected[corners])


def test_no_point_above_the_top_bound_near_a_point_is_inside():
    hf = _bumpy()
    radius = 0.004
    bound = hf.top_bound(radius)
    rng = np.random.default_rng(2)
    finite = 0
    for _ in range(300):
        c = rng.uniform([-0.025, -0.02], [0.025, 0.02])
        b = bound(*c)
        if not np.isfinite(b):
            continue
        finite += 1
        angle, r = rng.uniform(0, 2 * np.pi, 200), radius * np.sqrt(rng.random(200))
        pts = np.column_stack([c[0] + r * np.cos(angle), c[1] + r * np.sin(angle),
                               np.full(200, b + 1e-9)])
        depth, inside = hf.depth(pts)
        assert not inside.any() and depth.max() < 0.0
    assert finite > 100
    # close to the bound the surface is really there: the bound is not far too high
    assert bound(0.0, 0.0) <= hf.top.max() and bound(0.0, 0.0) >= hf.top[30, 40]


def test_points_off_the_grid_are_outside_on_every_side_and_corner():
    top = np.full((20, 30), 0.002)
    hf = HeightField(0.0, 0.0, 0.001, top, top - 0.01, np.ones((20, 30), bool))
    x1, y1 = 0.029, 0.019
    rng = np.random.default_rng(3)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            if dx == dy == 0:
                continue
            # 2 to 40 mm beyond the sides (both sides at a corner), at the pad's height
            off = rng.uniform(0.002, 0.04, size=(200, 2))
            x = np.where(dx < 0, -off[:, 0], np.where(dx > 0, x1 + off[:, 0], 0.015))
            y = np.where(dy < 0, -off[:, 1], np.where(dy > 0, y1 + off[:, 1], 0.010))
            depth, inside = hf.depth(np.column_stack([x, y, np.full(200, -0.001)]))
            assert not inside.any(), (dx, dy)
            assert (depth < -1.0).all(), (dx, dy, depth.max())
