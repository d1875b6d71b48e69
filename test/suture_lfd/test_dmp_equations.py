import numpy as np
from scipy.integrate import solve_ivp
from scipy.linalg import expm
from sim_bridge.common.geometry import (
    quaternion_conjugate,
    quaternion_from_rotvec,
    quaternion_product,
    rotvec_from_quaternion,
    so3_left_jacobian_apply,
)
from suture_lfd.dmp.equations import (
    basis_activations,
    basis_centres,
    basis_widths,
    canonical_phase,
    forcing_term,
    guarded_scale,
    linear_recurrence,
    lwr_weights,
    nonlinear_rate,
    normalised_features,
    transition_matrices,
)


def test_basis_follows_the_paper():
    c = basis_centres(100, 1.0)
    assert np.isclose(c[0], 1.0) and np.isclose(c[-1], np.exp(-1.0))
    assert np.allclose(basis_widths(c, 1.0), 100 ** 1.5 / c)
    assert np.allclose(canonical_phase([0.0, 1.0], 1.0), [1.0, np.exp(-1.0)])


def test_lwr_weights_are_the_papers_weighted_ratio():
    rng = np.random.default_rng(0)
    s = np.linspace(0.0, 1.0, 60)
    x = canonical_phase(s, 1.0)
    c = basis_centres(8, 1.0)
    psi = basis_activations(x, c, basis_widths(c, 1.0))
    F = rng.normal(size=(60, 2))
    offset = np.array([0.03, -0.02])
    W = lwr_weights(psi, x, F, offset)
    for i in range(8):
        Psi = np.diag(psi[:, i])
        for d in range(2):
            sv = x * offset[d]
            assert np.isclose(W[i, d], sv @ Psi @ F[:, d] / (sv @ Psi @ sv))


def test_forcing_term_is_the_normalised_weighted_sum_times_x_and_scale():
    rng = np.random.default_rng(1)
    x = canonical_phase(np.linspace(0.0, 1.0, 30), 1.0)
    c = basis_centres(6, 1.0)
    h = basis_widths(c, 1.0)
    W = rng.normal(size=(6, 3))
    scale = np.array([0.01, 1.0, -0.02])
    psi = basis_activations(x, c, h)
    expected = (psi @ W) / psi.sum(axis=1, keepdims=True) * x[:, None] * scale
    assert np.allclose(forcing_term(normalised_features(x, c, h), W, scale), expected)


def test_scale_guard_flags_only_degenerate_dimensions():
    scale, degenerate = guarded_scale([0.02, 1e-7, 0.0], [0.03, 0.012, 0.0], 1e-3, 1e-3)
    assert degenerate.tolist() == [False, True, True]
    assert scale.tolist() == [0.02, 1.0, 1.0]


def test_linear_recurrence_matches_a_loop():
    rng = np.random.default_rng(2)
    for _ in range(20):
        Phi = rng.normal(scale=0.5, size=(2, 2))
        n, d = int(rng.integers(1, 40)), int(rng.integers(1, 4))
        C = rng.normal(size=(2, d, n - 1))
        z0 = rng.normal(size=(2, d))
        expected = [z0]
        for k in range(n - 1):
            expected.append(Phi @ expected[-1] + C[:, :, k])
        got = linear_recurrence(Phi, C, z0)
        assert got.shape == (2, d, n)
        assert np.allclose(got, np.stack(expected, axis=-1), atol=1e-10)


def test_transition_matrices_integrate_a_linear_input_exactly():
    alpha, beta, h = 25.0, 6.25, 0.013
    M = np.array([[0.0, 1.0], [-alpha * beta, -alpha]])
    Phi, Gz, B0, B1 = transition_matrices(alpha, beta, h)
    assert np.allclose(Phi, expm(M * h))
    z0, held, u0, u1 = np.array([0.3, -1.0]), np.array([0.2, -0.4]), 2.0, -5.0

    def rhs(t, z):
        return M @ z + held + np.array([0.0, u0 + (u1 - u0) * t / h])

    exact = solve_ivp(rhs, (0.0, h), z0, rtol=1e-12, atol=1e-14).y[:, -1]
    got = Phi @ z0 + Gz @ held + B0[:, 1] * u0 + B1[:, 1] * u1
    assert np.allclose(got, exact, atol=1e-10)


def test_nonlinear_rate_is_the_rotation_vector_rate_minus_omega():
    rng = np.random.default_rng(3)
    axes = rng.normal(size=(50, 3))
    U = axes / np.linalg.norm(axes, axis=1, keepdims=True) * rng.uniform(0.01, 5.5, (50, 1))
    omega = rng.normal(size=(50, 3))
    dt = 1e-6
    q = quaternion_from_rotvec(U)
    later = quaternion_product(quaternion_from_rotvec(omega * dt), q)
    later_rotvec = rotvec_from_quaternion(later, shortest=False)   # literal log, same branch
    rate = (later_rotvec - U) / dt
    assert np.allclose(nonlinear_rate(U.T, omega.T).T, rate - omega, atol=1e-4)
    assert np.allclose(so3_left_jacobian_apply(U, rate), omega, atol=1e-4)
    axis = U / np.linalg.norm(U, axis=1, keepdims=True)
    assert np.allclose(nonlinear_rate(U.T, (2.0 * axis).T), 0.0, atol=1e-12)
    assert quaternion_conjugate(q).shape == q.shape
