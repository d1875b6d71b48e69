"""The suture thread: an inextensible, damped chain that hangs, follows and lies down."""

import numpy as np
import pytest
from sim_bridge.scene.thread import ThreadChain


def _straight(n=40, seg=0.0025, start=(0.0, 0.0, 0.1), direction=(1.0, 0.0, 0.0)):
    d = np.asarray(direction, dtype=float)
    return np.asarray(start) + np.outer(np.arange(n + 1) * seg, d / np.linalg.norm(d))


def _stretch(chain):
    lengths = np.linalg.norm(np.diff(chain.nodes, axis=0), axis=1)
    return np.abs(lengths / chain.rest_lengths - 1.0).max()


def test_a_thread_pinned_at_one_end_hangs_straight_down_without_stretching():
    chain = ThreadChain(_straight(), radius=0.0002)
    anchor = chain.nodes[0]
    for _ in range(1000):  # 10 s at 10 ms
        chain.step(0.01, anchor)
    nodes = chain.nodes
    assert _stretch(chain) < 1e-4
    assert np.linalg.norm(nodes[-1, :2] - anchor[:2]) < 1e-3
    assert nodes[-1, 2] == pytest.approx(anchor[2] - 0.1, abs=1e-3)
    assert chain.max_speed() < 1e-3


def test_node_zero_follows_a_fast_moving_anchor_and_the_chain_stays_finite():
    chain = ThreadChain(_straight(), radius=0.0002)
    start = chain.nodes[0]
    for k in range(2000):  # 4 s at 2 ms, 5 cm strokes at 1.5 Hz
        anchor = start + [0.05 * np.sin(9.4 * k * 0.002), 0.02 * np.cos(5.0 * k * 0.002), 0.0]
        chain.step(0.002, anchor)
        assert np.allclose(chain.nodes[0], anchor)
    assert np.all(np.isfinite(chain.nodes))
    assert _stretch(chain) < 1e-3


def test_a_thread_comes_to_lie_on_its_support():
    chain = ThreadChain(_straight(start=(0.0, 0.0, 0.02)), radius=0.0002)

    def support(xy):
        return 0.005 + 0.1 * xy[:, 0]  # a tilted surface

    anchor = chain.nodes[0]
    for _ in range(500):
        chain.step(0.01, anchor, support)
    nodes = chain.nodes
    floor = support(nodes[:, :2]) + 0.0002
    assert np.all(nodes[1:, 2] >= floor[1:] - 1e-9)
    touching = np.isclose(nodes[1:, 2], floor[1:], atol=1e-6)
    assert touching.sum() > 20  # most of the 10 cm lies on the surface
    assert _stretch(chain) < 1e-3


def test_same_inputs_give_bit_identical_chains():
    a = ThreadChain(_straight(), radius=0.0002)
    b = ThreadChain(_straight(), radius=0.0002)
    for k in range(300):
        anchor = [0.01 * np.sin(k * 0.05), 0.0, 0.1]
        a.step(0.002, anchor)
        b.step(0.002, anchor)
    assert np.array_equal(a.nodes, b.nodes)


def test_bad_nodes_are_rejected_with_the_reason():
    with pytest.raises(ValueError, match='shape'):
        ThreadChain(np.zeros((5, 2)), radius=0.0002)
    with pytest.raises(ValueError, match='zero length'):
        ThreadChain(np.zeros((5, 3)), radius=0.0002)
    with pytest.raises(ValueError, match='NaN'):
        ThreadChain(np.full((5, 3), np.nan), radius=0.0002)


def test_queued_steps_run_when_the_thread_is_read_and_give_the_same_nodes():
    calls = []

    def support(xy):
        calls.append(len(xy))
        return np.full(len(xy), 0.099) + 0.002 * np.sin(200.0 * xy[:, 0])

    stepped = ThreadChain(_straight(), radius=0.0002)
    queued = ThreadChain(_straight(), radius=0.0002)
    start = stepped.nodes[0]
    for k in range(300):
        anchor = start + [0.03 * np.sin(6.0 * k * 0.01), 0.01 * np.cos(4.0 * k * 0.01), 0.0]
        stepped.step(0.01, anchor, support)
        before = len(calls)
        queued.follow(0.01, anchor, support)
        assert len(calls) == before  # nothing runs until the thread is read
        if k % 37 == 0:
            assert np.array_equal(queued.nodes, stepped.nodes)
    assert np.array_equal(queued.velocities, stepped.velocities)
    assert queued.max_speed() == stepped.max_speed()
    assert np.array_equal(queued.nodes, stepped.nodes)


def test_a_thread_nobody_reads_keeps_a_bounded_queue_running_its_oldest_steps(monkeypatch):
    from sim_bridge.scene import thread as thread_module

    monkeypatch.setattr(thread_module, '_MAX_QUEUED', 5)
    calls = []

    def support(xy):
        calls.append(len(xy))
        return np.full(len(xy), 0.099)

    stepped = ThreadChain(_straight(), radius=0.0002)
    queued = ThreadChain(_straight(), radius=0.0002)
    start = stepped.nodes[0]
    for k in range(40):
        anchor = start + [0.02 * np.sin(5.0 * k * 0.01), 0.0, 0.0]
        stepped.step(0.01, anchor, support)
        queued.follow(0.01, anchor, support)
    assert len(calls) == 40 + 35  # beyond five queued steps, one runs per new step
    assert np.array_equal(queued.nodes, stepped.nodes)
    assert len(calls) == 80
