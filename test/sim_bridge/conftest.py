"""Fixtures of the simulator's tests: ``client``, a PyBullet client of its own (no GUI)."""

import pytest
from sim_bridge.bullet import bullet_client, pybullet


@pytest.fixture()
def client():
    """Give the test a PyBullet client in DIRECT mode, disconnected at teardown."""
    c = bullet_client.BulletClient(connection_mode=pybullet.DIRECT)
    yield c
    c.disconnect()
