"""Rotations: skew, SO(3) exponential/logarithm, DCM <-> Euler (ZYX), and the
attitude ⊕ / ⊖ pair used by the error-state filters.

Conventions (see docs/conventions.md):

* ``C_bn`` is the direction cosine matrix from body to navigation frame
  (C_b^n), so ``v_n = C_bn @ v_b``.
* Euler angles are ``[roll, pitch, yaw]`` [rad], ZYX order:
  ``C_bn = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.
* Every function is batched over leading axes: vectors are ``(..., 3)`` and
  matrices ``(..., 3, 3)``.
* ``attitude_plus(C_bn, dpsi) = exp([dpsi x]) @ C_bn`` (a nav-frame misalignment
  applied on the left) and ``attitude_minus(C1, C2) = log(C1 @ C2^T)`` are
  inverse to each other: ``attitude_minus(attitude_plus(C, d), C) == d``.
"""
from __future__ import annotations

import numpy as np

_SMALL = 1e-4  # below this angle [rad] the log's Taylor series is exact to double precision
_SERIES2 = 1e-4  # squared angle (0.01 rad) below which the 3-term nested series is used for a whole batch


def skew(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix ``[v x]`` of ``v`` (..., 3) -> (..., 3, 3)."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def vee(S: np.ndarray) -> np.ndarray:
    """Inverse of :func:`skew` for the antisymmetric part of ``S`` (..., 3, 3) -> (..., 3)."""
    return 0.5 * np.stack(
        [S[..., 2, 1] - S[..., 1, 2], S[..., 0, 2] - S[..., 2, 0], S[..., 1, 0] - S[..., 0, 1]],
        axis=-1,
    )


def exp_so3(phi: np.ndarray) -> np.ndarray:
    """Rotation matrix ``exp([phi x])`` of rotation vectors ``phi`` (..., 3) [rad] -> (..., 3, 3).

    Rodrigues' formula with Taylor series below 1e-4 rad, exact to double precision.
    """
    return _exp_parts(np.asarray(phi, dtype=float), minus_identity=False)


def exp_so3_minus_identity(phi: np.ndarray) -> np.ndarray:
    """``exp([phi x]) - I`` (..., 3, 3) without the cancellation of forming exp first.

    Used where a small rotation acts on a large vector and only the change matters.
    """
    return _exp_parts(np.asarray(phi, dtype=float), minus_identity=True)


def _exp_parts(phi: np.ndarray, minus_identity: bool) -> np.ndarray:
    th2 = (phi * phi).sum(axis=-1)
    # per element: below 0.01 rad (every IMU step) the series to th^6 is exact to double
    # precision; larger angles use sin/cos. The choice never depends on the rest of the batch.
    a = np.asarray(1.0 - th2 / 6.0 * (1.0 - th2 / 20.0 * (1.0 - th2 / 42.0)))
    b = np.asarray(0.5 - th2 / 24.0 * (1.0 - th2 / 30.0 * (1.0 - th2 / 56.0)))
    big = th2 >= _SERIES2
    if big.any():
        th = np.sqrt(th2[big])
        a[big] = np.sin(th) / th
        b[big] = (1.0 - np.cos(th)) / (th * th)
    # [phi x]^2 = phi phi^T - theta^2 I, so exp = (1 - b theta^2) I + a [phi x] + b phi phi^T
    out = skew(phi * a[..., None]) + b[..., None, None] * (phi[..., :, None] * phi[..., None, :])
    diag = -b * th2 if minus_identity else 1.0 - b * th2
    out[..., 0, 0] += diag
    out[..., 1, 1] += diag
    out[..., 2, 2] += diag
    return out


def log_so3(C: np.ndarray) -> np.ndarray:
    """Rotation vector [rad] of rotation matrices ``C`` (..., 3, 3) -> (..., 3); |result| <= pi.

    Uses ``atan2(|s|, c)`` on the antisymmetric and trace parts, so it is accurate for
    small angles (no arccos), with a symmetric-part branch near pi.
    """
    C = np.asarray(C, dtype=float)
    s = vee(C)  # sin(theta) * axis
    c = 0.5 * (np.trace(C, axis1=-2, axis2=-1) - 1.0)
    sn = np.linalg.norm(s, axis=-1)
    th = np.arctan2(sn, c)
    small = th < _SMALL
    sn_safe = np.where(sn == 0.0, 1.0, sn)
    scale = np.where(small, 1.0 + th * th / 6.0 + 7.0 * th**4 / 360.0, th / sn_safe)
    out = scale[..., None] * s
    near_pi = c < -0.99
    if np.any(near_pi):
        # axis from the symmetric part: C + I - ... : B = (C + C^T)/2 - c I = (1 - c) a a^T
        Cn = C[near_pi]
        cn = c[near_pi]
        B = 0.5 * (Cn + np.swapaxes(Cn, -1, -2)) - cn[:, None, None] * np.eye(3)
        diag = np.einsum("...ii->...i", B)
        k = np.argmax(diag, axis=-1)
        col = np.take_along_axis(B, k[:, None, None].repeat(3, axis=1), axis=2)[..., 0]
        axis = col / np.linalg.norm(col, axis=-1, keepdims=True)
        sgn = np.sign(np.einsum("...i,...i->...", axis, s[near_pi]))
        sgn = np.where(sgn == 0, 1.0, sgn)
        out[near_pi] = (sgn * th[near_pi])[:, None] * axis
    return out


def euler_to_dcm(euler: np.ndarray) -> np.ndarray:
    """C_b^n from ``[roll, pitch, yaw]`` (..., 3) [rad], ZYX: Rz(yaw) Ry(pitch) Rx(roll)."""
    euler = np.asarray(euler, dtype=float)
    r, p, y = euler[..., 0], euler[..., 1], euler[..., 2]
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    C = np.empty(euler.shape[:-1] + (3, 3))
    C[..., 0, 0] = cp * cy
    C[..., 0, 1] = sr * sp * cy - cr * sy
    C[..., 0, 2] = cr * sp * cy + sr * sy
    C[..., 1, 0] = cp * sy
    C[..., 1, 1] = sr * sp * sy + cr * cy
    C[..., 1, 2] = cr * sp * sy - sr * cy
    C[..., 2, 0] = -sp
    C[..., 2, 1] = sr * cp
    C[..., 2, 2] = cr * cp
    return C


def dcm_to_euler(C: np.ndarray) -> np.ndarray:
    """``[roll, pitch, yaw]`` (..., 3) [rad] of C_b^n (..., 3, 3); yaw in (-pi, pi]."""
    C = np.asarray(C, dtype=float)
    roll = np.arctan2(C[..., 2, 1], C[..., 2, 2])
    pitch = np.arctan2(-C[..., 2, 0], np.hypot(C[..., 2, 1], C[..., 2, 2]))
    yaw = np.arctan2(C[..., 1, 0], C[..., 0, 0])
    return np.stack([roll, pitch, yaw], axis=-1)


def attitude_plus(C_bn: np.ndarray, dpsi: np.ndarray) -> np.ndarray:
    """⊕ (ukf-nespm.md eq 37): apply a nav-frame misalignment ``dpsi`` (..., 3) [rad].

    Returns ``exp([dpsi x]) @ C_bn`` (..., 3, 3).
    """
    return exp_so3(dpsi) @ C_bn


def attitude_minus(C1_bn: np.ndarray, C2_bn: np.ndarray) -> np.ndarray:
    """⊖ (ukf-nespm.md eq 40): nav-frame misalignment taking ``C2_bn`` to ``C1_bn``.

    Returns ``log(C1_bn @ C2_bn^T)`` (..., 3) [rad], so that
    ``attitude_plus(C2_bn, attitude_minus(C1_bn, C2_bn)) == C1_bn``.
    """
    return log_so3(C1_bn @ np.swapaxes(C2_bn, -1, -2))


def orthonormalize(C: np.ndarray) -> np.ndarray:
    """Nearest rotation matrix (polar factor via SVD) of ``C`` (..., 3, 3)."""
    U, _, Vt = np.linalg.svd(C)
    return U @ Vt


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Angle(s) [rad] wrapped to (-pi, pi] (the yaw range of docs/conventions.md).

    The one wrapping function: ``mod(a + pi, 2 pi) - pi``, with -pi mapped to pi.
    """
    a = np.asarray(a, dtype=float)
    w = np.mod(a + np.pi, 2.0 * np.pi) - np.pi
    return np.where(w == -np.pi, np.pi, w)


#: below this squared angle [rad²] the SO(3) Jacobian coefficients use their series (exact to double
#: precision: the first omitted term is θ⁸/3.6e6 ≈ 3e-23 relative)
SERIES_TH2 = 1e-4


def so3_left_jacobian(phi: np.ndarray) -> np.ndarray:
    """Left Jacobian of SO(3) ``J_l(φ) = I + (1 − cos θ)/θ² [φ×] + (θ − sin θ)/θ³ [φ×]²``.

    ``phi`` (..., 3) [rad] -> (..., 3, 3). Series below θ = 0.01 rad, per element.
    """
    phi = np.asarray(phi, dtype=float)
    th2 = (phi * phi).sum(axis=-1)
    b = np.asarray(0.5 - th2 / 24.0 * (1.0 - th2 / 30.0 * (1.0 - th2 / 56.0)))
    c = np.asarray(1.0 / 6.0 - th2 / 120.0 * (1.0 - th2 / 42.0 * (1.0 - th2 / 72.0)))
    big = th2 >= SERIES_TH2
    if big.any():
        th = np.sqrt(th2[big])
        b[big] = (1.0 - np.cos(th)) / th2[big]
        c[big] = (th - np.sin(th)) / (th2[big] * th)
    S = skew(phi)
    return np.eye(3) + b[..., None, None] * S + c[..., None, None] * (S @ S)


def so3_left_jacobian_inverse(phi: np.ndarray) -> np.ndarray:
    """``J_l(φ)⁻¹ = I − ½ [φ×] + (1/θ² − (1 + cos θ)/(2 θ sin θ)) [φ×]²`` (..., 3, 3), |φ| < π."""
    phi = np.asarray(phi, dtype=float)
    th2 = (phi * phi).sum(axis=-1)
    d = np.asarray(1.0 / 12.0 + th2 / 720.0 + th2 * th2 / 30240.0 + th2**3 / 1209600.0)
    big = th2 >= SERIES_TH2
    if big.any():
        th = np.sqrt(th2[big])
        d[big] = 1.0 / th2[big] - (1.0 + np.cos(th)) / (2.0 * th * np.sin(th))
    S = skew(phi)
    return np.eye(3) - 0.5 * S + d[..., None, None] * (S @ S)


def signed_permutations() -> np.ndarray:
    """All 48 signed 3x3 permutation matrices (48, 3, 3), the identity first."""
    import itertools

    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            A = np.zeros((3, 3))
            A[np.arange(3), perm] = signs
            out.append(A)
    out.sort(key=lambda A: not np.array_equal(A, np.eye(3)))
    return np.array(out)
