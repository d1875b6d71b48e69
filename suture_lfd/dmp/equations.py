"""
The seed paper's DMP equations as plain functions (Ijspeert 2013 position, Ude 2014 quaternion).

Time is normalised: ``s = (t - t0) / tau`` runs from 0 to 1 over the movement, ``tau`` being its
duration in seconds, so the paper's ``tau = 1`` system is used for a movement of any length
(lfd_anchors section 2.1). Primes are derivatives with respect to ``s``.

Canonical system::

    x' = -alpha_x x,            x(s) = exp(-alpha_x s)

Position (per dimension)::

    y'' = alpha_y (beta_y (g - y) - y') + f(x)
    f(x) = sum_i psi_i(x) w_i / sum_i psi_i(x) * x * (g - y0)
    psi_i(x) = exp(-h_i (x - c_i)^2),   c_i = exp(-alpha_x i/(N-1)),   h_i = N^1.5 / (alpha_x c_i)

Orientation (unit quaternion ``q``, world angular velocity ``omega``)::

    omega' = alpha_z (beta_z 2 log(g * conj(q)) - omega) + f_o(x)
    q(s + ds) = exp(omega ds / 2) * q(s)
    f_o(x) = D_o sum_i psi_i w_i / sum_i psi_i * x,   D_o = diag(2 log(g * conj(q0)))

with Ude's literal logarithm ``log(q) = arccos(w) v/|v|`` (no hemisphere flip), so a rotation
of more than 180 degrees keeps its direction (lfd_anchors section 2.5).

Weights (locally weighted regression, the paper's eq. for ``w_i``)::

    w_i = s^T Psi_i F_d / s^T Psi_i s,   s = x (g - y0),   Psi_i = diag(psi_i(t_0..t_n))

Scaling guard (lfd_anchors section 2.3): a dimension whose ``|g - y0|`` is below
``scale_guard * max(range, floor)`` is learnt and executed with the factor set to 1
(unscaled weights), so a start and goal that coincide in one axis neither lose the excursion
nor amplify it when the goal moves.

Integration: the transformation systems are linear in their state. Each step is integrated
exactly (matrix exponential) with the forcing term linear over the step (first-order hold);
the orientation system is written in the goal-relative rotation vector ``u = 2 log(q * conj(g))``
where it reads ``u' = omega + n(u, omega)``, ``omega' = -alpha_z beta_z u - alpha_z omega + f_o``
with ``n = J_l(u)^-1 omega - omega`` held over the step.

Size: the equations of the seed paper on one page, each a short plain function whose docstring
carries its formula.
"""

from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike
from scipy.linalg import expm
from scipy.signal import lfilter
from sim_bridge.common.geometry import (
    quaternion_conjugate,
    quaternion_log,
    quaternion_product,
   so3_left_jacobian_apply,
)
from sim_bridge.common.validation import FloatArray


def canonical_phase(s: ArrayLike, alpha_x: float) -> FloatArray:
    """
    Return the phase ``x(s) = exp(-alpha_x s)`` of the canonical system.

    Parameters
    ----------
    s : array_like, shape (n,)
        Normalised time ``t / tau`` (0 at the start, 1 at the end of the movement).
    alpha_x : float
        Canonical gain (the paper's Table I: 1).

    Returns
    -------
    ndarray, shape (n,)
        Phase, from 1 down towards 0.

    """
    return np.exp(-alpha_x * np.asarray(s, dtype=float))


def basis_centres(n_bfs: int, alpha_x: float) -> FloatArray:
    """
    Return the basis centres ``c_i = exp(-alpha_x i / (N - 1))``, evenly spaced in time.

    Parameters
    ----------
    n_bfs : int
        Number of basis functions ``N``.
    alpha_x : float
        Canonical gain.

    Returns
    -------
    ndarray, shape (n_bfs,)
        Centres in phase ``x``.

    """
    return np.exp(-alpha_x * np.linspace(0.0, 1.0, n_bfs))


def basis_widths(centres: ArrayLike, alpha_x: float) -> FloatArray:
    """
    Return the widths ``h_i = N^1.5 / (alpha_x c_i)`` (seed paper, eq. for ``f(x)``).

    Parameters
    ----------
    centres : array_like, shape (n_bfs,)
        Basis centres ``c_i``.
    alpha_x : float
        Canonical gain.

    Returns
    -------
    ndarray, shape (n_bfs,)
        Widths ``h_i`` (inverse squared phase units).

    """
    centres = np.asarray(centres, dtype=float)
    return centres.size ** 1.5 / (alpha_x * centres)


def basis_activations(x: ArrayLike, centres: FloatArray, widths: FloatArray) -> FloatArray:
    """
    Return the Gaussian activations ``psi_i(x) = exp(-h_i (x - c_i)^2)``.

    Parameters
    ----------
    x : array_like, shape (n,)
        Phase values.
    centres, widths : ndarray, shape (n_bfs,)
        ``c_i`` and ``h_i``.

    Returns
    -------
    ndarray, shape (n, n_bfs)
        Activations.

    """
    x = np.asarray(x, dtype=float)
    return np.exp(-widths * (x[:, None] - centres) ** 2)


def normalised_features(x: ArrayLike, centres: FloatArray, widths: FloatArray) -> FloatArray:
    """
    Return ``psi_i(x) x / sum_j psi_j(x)``, the regressors of the forcing term.

    Parameters
    ----------
    x : array_like, shape (n,)
        Phase values.
    centres, widths : ndarray, shape (n_bfs,)
        ``c_i`` and ``h_i``.

    Returns
    -------
    ndarray, shape (n, n_bfs)
        Features; ``forcing = features @ weights * scale``.

    """
    x = np.asarray(x, dtype=float)
    return _normalised(basis_activations(x, centres, widths), x)


def _normalised(psi: FloatArray, x: FloatArray) -> FloatArray:
    """Return ``psi_i x / sum_j psi_j`` from activations ``psi`` (n, n_bfs) at phases ``x``."""
    total = psi.sum(axis=1, keepdims=True)
    return psi * (x[:, None] / np.where(total > 1e-300, total, 1e-300))


@lru_cache(maxsize=32)
def _uniform_phase(n_pts: int, alpha_x: float) -> FloatArray:
    x = canonical_phase(np.linspace(0.0, 1.0, n_pts), alpha_x)
    x.flags.writeable = False
    return x


@lru_cache(maxsize=32)
def _uniform_activations(n_pts: int, n_bfs: int, alpha_x: float) -> FloatArray:
    centres = basis_centres(n_bfs, alpha_x)
    psi = basis_activations(_uniform_phase(n_pts, alpha_x), centres,
                            basis_widths(centres, alpha_x))
    psi.flags.writeable = False
    return psi


@lru_cache(maxsize=32)
def _uniform_features(n_pts: int, n_bfs: int, alpha_x: float) -> tuple[FloatArray, FloatArray]:
    x = _uniform_phase(n_pts, alpha_x)
    features = _normalised(_uniform_activations(n_pts, n_bfs, alpha_x), x)
    features.flags.writeable = False
    return x, features


def uniform_phase(n_pts: int, alpha_x: float) -> FloatArray:
    """
    Return the phase ``x`` on ``n_pts`` evenly spaced samples of ``s`` in [0, 1] (cached).

    Parameters
    ----------
    n_pts : int
        Number of samples.
    alpha_x : float
        Canonical gain.

    Returns
    -------
    ndarray, shape (n_pts,)
        Phase (read-only).

    """
    return _uniform_phase(int(n_pts), float(alpha_x))


def uniform_activations(n_pts: int, n_bfs: int, alpha_x: float) -> FloatArray:
    """
    Return the activations ``psi_i`` on ``n_pts`` evenly spaced samples of ``s`` in [0, 1].

    Cached: learning many demonstrations of the same length reuses the matrix.

    Parameters
    ----------
    n_pts : int
        Number of samples.
    n_bfs : int
        Number of basis functions.
    alpha_x : float
        Canonical gain.

    Returns
    -------
    ndarray, shape (n_pts, n_bfs)
        ``psi_i(x(s_k))`` (read-only).

    """
    return _uniform_activations(int(n_pts), int(n_bfs), float(alpha_x))


def uniform_features(n_pts: int, n_bfs: int, alpha_x: float) -> tuple[FloatArray, FloatArray]:
    """
    Return phase and forcing features on ``n_pts`` evenly spaced samples of ``s`` in [0, 1].

    Cached: executing the same primitive many times reuses the matrix.

    Parameters
    ----------
    n_pts : int
        Number of samples.
    n_bfs : int
        Number of basis functions.
    alpha_x : float
        Canonical gain.

    Returns
    -------
    x : ndarray, shape (n_pts,)
        Phase (read-only).
    features : ndarray, shape (n_pts, n_bfs)
        ``psi_i x / sum psi`` (read-only).

    """
    return _uniform_features(int(n_pts), int(n_bfs), float(alpha_x))


def forcing_term(features: FloatArray, weights: FloatArray, scale: ArrayLike) -> FloatArray:
    """
    Return the forcing term ``f = sum psi_i w_i / sum psi_i * x * scale``.

    Parameters
    ----------
    features : ndarray, shape (n, n_bfs)
        From :func:`normalised_features`.
    weights : ndarray, shape (n_bfs, n_dims)
        Learnt weights.
    scale : array_like, shape (n_dims,)
        ``g - y0`` (position), the diagonal of ``D_o`` (orientation), 1 where guarded.

    Returns
    -------
    ndarray, shape (n, n_dims)
        Forcing term (acceleration units in normalised time).

    """
    return (features @ weights) * np.asarray(scale, dtype=float)


def guarded_scale(offset: ArrayLike, spread: ArrayLike, guard: float,
                  floor: float) -> tuple[FloatArray, FloatArray]:
    """
    Return the per-dimension forcing scale and which dimensions are degenerate.

    Parameters
    ----------
    offset : array_like, shape (n_dims,)
        ``g - y0`` (m) or ``2 log(g * conj(q0))`` (rad).
    spread : array_like, shape (n_dims,)
        Range of the demonstration in each dimension (same unit).
    guard : float
        Relative threshold (``DmpParams.scale_guard``).
    floor : float
        Smallest range used for the threshold (same unit as ``offset``).

    Returns
    -------
    scale : ndarray, shape (n_dims,)
        ``offset`` where it is usable, 1 in degenerate dimensions.
    degenerate : ndarray of bool, shape (n_dims,)
        True where ``|offset| < guard * max(spread, floor)``.

    """
    offset = np.asarray(offset, dtype=float)
    degenerate = np.abs(offset) < guard * np.maximum(np.asarray(spread, dtype=float), floor)
    return np.where(degenerate, 1.0, offset), degenerate


def lwr_weights(psi: FloatArray, x: FloatArray, targets: FloatArray,
                scale: ArrayLike) -> FloatArray:
    """
    Return LWR weights ``w_i = s^T Psi_i F_d / s^T Psi_i s`` with ``s = x * scale``.

    Parameters
    ----------
    psi : ndarray, shape (n, n_bfs)
        Activations ``psi_i(x(t_k))``.
    x : ndarray, shape (n,)
        Phase at the samples.
    targets : ndarray, shape (n, n_dims)
        Desired forcing term ``F_d`` at the samples.
    scale : array_like, shape (n_dims,)
        ``g - y0`` per dimension (1 where guarded).

    Returns
    -------
    ndarray, shape (n_bfs, n_dims)
        Weights; a basis function without support in the data gets weight 0.

    """
    scale = np.asarray(scale, dtype=float)
    d = targets.shape[1]
    stacked = np.empty((x.size, d + 1))
    np.multiply(x[:, None], targets, out=stacked[:, :d])
    np.multiply(x, x, out=stacked[:, d])
    sums = psi.T @ stacked
    numerator = sums[:, :d]                             # sum_k psi_ik x_k F_kd
    denominator = sums[:, d]                            # sum_k psi_ik x_k^2
    ok = denominator > 1e-300
    weights = np.where(ok[:, None], numerator / np.where(ok, denominator, 1.0)[:, None], 0.0)
    return weights / scale


def least_squares_weights(psi: FloatArray, x: FloatArray, targets: FloatArray, scale: ArrayLike,
                          ridge: float = 1e-8) -> FloatArray:
    """
    Return the weights that fit the whole forcing term at once (ridge least squares).

    With the features ``X_ki = psi_i(x_k) x_k / sum_j psi_j(x_k)`` of the forcing term,
    ``w = (X^T X + lambda I)^-1 X^T F_d / scale``, ``lambda = ridge * trace(X^T X) / n_bfs``.
    LWR (:func:`lwr_weights`) fits each basis function on its own, a weighted average of the
    target under it; where neighbouring bases overlap (the widths ``N^1.5 / (alpha_x c_i)``
    span two to three centre spacings) it smooths the target, and a movement shorter than
    that span is lost. The least-squares fit of the same bases keeps it.

    Parameters
    ----------
    psi : ndarray, shape (n, n_bfs)
        Activations ``psi_i(x(t_k))``.
    x : ndarray, shape (n,)
        Phase at the samples.
    targets : ndarray, shape (n, n_dims)
        Desired forcing term ``F_d`` at the samples.
    scale : array_like, shape (n_dims,)
        ``g - y0`` per dimension (1 where guarded).
    ridge : float
        Relative regularisation (>= 0).

    Returns
    -------
    ndarray, shape (n_bfs, n_dims)

    """
    X = _normalised(psi, x)
    A = X.T @ X
    lam = ridge * float(np.trace(A)) / A.shape[0]
    A[np.diag_indices_from(A)] += lam
    weights = np.linalg.lstsq(A, X.T @ targets, rcond=None)[0]
    return weights / np.asarray(scale, dtype=float)


def derivative(Y: FloatArray, s: float | FloatArray) -> FloatArray:
    """
    Return ``dY/ds`` by second-order finite differences, second order at the ends too.

    ``numpy.gradient(Y, s, axis=0, edge_order=2)``, written out for an even spacing.

    Parameters
    ----------
    Y : ndarray, shape (n, n_dims)
        Samples (``n >= 3``).
    s : float or ndarray, shape (n,)
        Sample times, or their spacing when evenly spaced.

    Returns
    -------
    ndarray, shape (n, n_dims)

    """
    if not isinstance(s, float):
        return np.gradient(Y, s, axis=0, edge_order=2)
    out = np.empty_like(Y)
    np.subtract(Y[2:], Y[:-2], out=out[1:-1])
    out[0] = 4.0 * Y[1] - 3.0 * Y[0] - Y[2]
    out[-1] = 3.0 * Y[-1] - 4.0 * Y[-2] + Y[-3]
    out *= 0.5 / s
    return out


def position_forcing_target(s: float | FloatArray, Y: FloatArray, goal: FloatArray, alpha_y: float,
                            beta_y: float) -> FloatArray:
    """
    Return the desired forcing term ``F_d = y'' - alpha_y (beta_y (g - y) - y')``.

    Derivatives with respect to the normalised time ``s`` come from second-order finite
    differences (``numpy.gradient``, second order at the ends too).

    Parameters
    ----------
    s : float or ndarray, shape (n,)
        Normalised sample times in [0, 1], or their spacing when evenly spaced.
    Y : ndarray, shape (n, n_dims)
        Demonstrated positions, m.
    goal : ndarray, shape (n_dims,)
        Demonstrated goal, m.
    alpha_y, beta_y : float
        Gains.

    Returns
    -------
    ndarray, shape (n, n_dims)
        ``F_d``, m per squared normalised time.

    """
    Yd = derivative(Y, s)
    Ydd = derivative(Yd, s)
    return Ydd - alpha_y * (beta_y * (goal - Y) - Yd)


def quaternion_forcing_target(s: float | FloatArray, Q: FloatArray, goal: FloatArray,
                              alpha_z: float, beta_z: float) -> tuple[FloatArray, FloatArray]:
    """
    Return ``F_d = omega' - alpha_z (beta_z 2 log(g * conj(q)) - omega)`` for a quaternion demo.

    ``omega`` is obtained from the goal-relative rotation vector ``u = 2 log(q * conj(g))``
    (literal log) as ``omega = J_l(u) u'``; ``u'`` and ``omega'`` by second-order differences.

    Parameters
    ----------
    s : float or ndarray, shape (n,)
        Normalised sample times in [0, 1], or their spacing when evenly spaced.
    Q : ndarray, shape (n, 4)
        Sign-continuous unit quaternions (x, y, z, w).
    goal : ndarray, shape (4,)
        Goal quaternion (the last sample, same sign convention).
    alpha_z, beta_z : float
        Gains.

    Returns
    -------
    F : ndarray, shape (n, 3)
        ``F_d``, rad per squared normalised time.
    U : ndarray, shape (n, 3)
        ``u = 2 log(q * conj(g))``, rad (``-U[0]`` is the diagonal of ``D_o``).

    """
    U = 2.0 * quaternion_log(quaternion_product(Q, quaternion_conjugate(goal)))
    Ud = derivative(U, s)
    W = so3_left_jacobian_apply(U, Ud)
    Wd = derivative(W, s)
    return Wd + alpha_z * (beta_z * U + W), U


def nonlinear_rate(U: FloatArray, W: FloatArray) -> FloatArray:
    """
    Return ``n = J_l(u)^-1 omega - omega``, the nonlinear part of ``u' = omega + n``.

    ``n = -1/2 u x omega + c(a) u x (u x omega)`` with ``a = |u|`` and
    ``c(a) = 1/a^2 - (1 + cos a) / (2 a sin a)``; zero when the rotation stays about one axis.

    Parameters
    ----------
    U : ndarray, shape (3, ...)
        Goal-relative rotation vectors ``2 log(q * conj(g))``, rad, components first.
    W : ndarray, shape (3, ...)
        Angular velocities (world), rad per normalised time, components first.

    Returns
    -------
    ndarray, shape (3, ...)
        ``n``, components first.

    """
    U = np.asarray(U, dtype=float)
    W = np.asarray(W, dtype=float)
    a2 = (U * U).sum(axis=0)
    dot = (U * W).sum(axis=0)
    a = np.sqrt(a2)
    # (1 + cos a) / sin a = 1 / tan(a / 2): one transcendental call per sample
    with np.errstate(divide='ignore', invalid='ignore'):
        c = 1.0 / a2 - 0.5 / (a * np.tan(0.5 * a))
    small = a < 1e-3
    if small.any():
        c = np.where(small, 1.0 / 12.0 + a2 / 720.0, c)
    # n = c u x (u x w) - u x w / 2, with u x (u x w) = u (u . w) - w |u|^2
    n = U * dot
    n -= W * a2
    n *= c
    ux, uy, uz = U
    wx, wy, wz = W
    n[0] -= 0.5 * (uy * wz - uz * wy)
    n[1] -= 0.5 * (uz * wx - ux * wz)
    n[2] -= 0.5 * (ux * wy - uy * wx)
    return n


@lru_cache(maxsize=256)
def transition_matrices(alpha: float, beta: float,
                        h: float) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """
    Return the exact discretisation of ``[e, v]' = M [e, v] + [a, b]``.

    ``M = [[0, 1], [-alpha beta, -alpha]]``.

    Over a step ``h`` of normalised time, with input ``[a, b]`` either held (zero-order hold)
    or linear between its values at both ends (first-order hold)::

        state(h) = Phi state(0) + Gz [a, b] + B0 [a0, b0] + B1 [a1, b1]

    Parameters
    ----------
    alpha, beta : float
        Gains of the transformation system.
    h : float
        Step, normalised time.

    Returns
    -------
    Phi, Gz, B0, B1 : ndarray, shape (2, 2)
        State transition, zero-order-hold input matrix, first-order-hold matrices (start and
        end of the step). All read-only.

    """
    M = np.array([[0.0, 1.0], [-alpha * beta, -alpha]])
    E = np.zeros((6, 6))
    E[:2, :2] = M
    E[:2, 2:4] = np.eye(2)
    E[2:4, 4:6] = np.eye(2)
    F = expm(E * h)
    Phi, G1, G2 = F[:2, :2], F[:2, 2:4], F[:2, 4:6]
    out = (Phi.copy(), G1.copy(), G1 - G2 / h, G2 / h)
    for array in out:
        array.flags.writeable = False
    return out


def linear_recurrence(Phi: FloatArray, C: FloatArray, state0: FloatArray) -> FloatArray:
    """
    Return the states of ``z_{k+1} = Phi z_k + c_k`` for all k, without a Python loop.

    Each component obeys the scalar recurrence
    ``z_{k+2} = tr(Phi) z_{k+1} - det(Phi) z_k + c_{k+1} + (Phi - tr(Phi) I) c_k``
    (Cayley-Hamilton), which ``scipy.signal.lfilter`` runs in compiled code.

    Parameters
    ----------
    Phi : ndarray, shape (2, 2)
        Transition matrix.
    C : ndarray, shape (2, n_dims, n - 1)
        Inputs ``c_0 .. c_{n-2}`` (state component, dimension, step).
    state0 : ndarray, shape (2, n_dims)
        ``z_0``.

    Returns
    -------
    ndarray, shape (2, n_dims, n)
        ``z_0 .. z_{n-1}``.

    """
    n = C.shape[-1] + 1
    out = np.empty(C.shape[:-1] + (n,))
    out[..., 0] = state0
    if n == 1:
        return out
    z1 = Phi @ state0 + C[..., 0]
    out[..., 1] = z1
    if n == 2:
        return out
    tr = Phi[0, 0] + Phi[1, 1]
    det = Phi[0, 0] * Phi[1, 1] - Phi[0, 1] * Phi[1, 0]
    drive = C[..., 1:].copy()
    drive[0] += (Phi[0, 0] - tr) * C[0, :, :-1] + Phi[0, 1] * C[1, :, :-1]
    drive[1] += Phi[1, 0] * C[0, :, :-1] + (Phi[1, 1] - tr) * C[1, :, :-1]
    zi = np.stack((tr * z1 - det * state0, -det * z1), axis=-1)
    out[..., 2:], _ = lfilter([1.0], [1.0, -tr, det], drive, axis=-1, zi=zi)
    return out


def input_response(Phi: FloatArray, gain: FloatArray, N: FloatArray) -> FloatArray:
    """
    Return ``z_1 .. z_n`` of ``z_{k+1} = Phi z_k + gain n_k`` from ``z_0 = 0``.

    The zero-state part of :func:`linear_recurrence` for an input that enters along one vector:
    per component the transfer function ``(q I - Phi)^-1 gain``, two ``lfilter`` calls.

    Parameters
    ----------
    Phi : ndarray, shape (2, 2)
        Transition matrix.
    gain : ndarray, shape (2,)
        Input vector.
    N : ndarray, shape (n_dims, n)
        Inputs ``n_0 .. n_{n-1}``.

    Returns
    -------
    ndarray, shape (2, n_dims, n)
        ``z_1 .. z_n``.

    """
    b_u, b_w, a = input_filters(Phi, gain)
    out = np.empty((2,) + N.shape)
    out[0] = lfilter(b_u, a, N, axis=-1)
    out[1] = lfilter(b_w, a, N, axis=-1)
    return out


def input_filters(Phi: FloatArray,
                  gain: FloatArray) -> tuple[list[float], list[float], list[float]]:
    """
    Return the ``lfilter`` coefficients ``(b_u, b_w, a)`` of :func:`input_response`.

    Parameters
    ----------
    Phi : ndarray, shape (2, 2)
        Transition matrix.
    gain : ndarray, shape (2,)
        Input vector.

    Returns
    -------
    b_u, b_w : list of float
        Numerators for the first and second state component (output ``z_{k+1}`` for input
        ``n_k``).
    a : list of float
        Common denominator ``[1, -tr(Phi), det(Phi)]``.

    """
    tr = Phi[0, 0] + Phi[1, 1]
    det = Phi[0, 0] * Phi[1, 1] - Phi[0, 1] * Phi[1, 0]
    g0, g1 = float(gain[0]), float(gain[1])
    b_u = [g0, (Phi[0, 0] - tr) * g0 + Phi[0, 1] * g1]
    b_w = [g1, Phi[1, 0] * g0 + (Phi[1, 1] - tr) * g1]
    return b_u, b_w, [1.0, -tr, det]
