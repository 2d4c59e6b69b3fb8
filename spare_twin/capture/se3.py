"""Rigid motions (4x4, metres) written out so that every sum over points has a fixed order (no BLAS
products over points, whose threading may reorder them): the registration's byte-reproducibility rests
on it (`spare_twin.capture.registration`)."""

from __future__ import annotations

import numpy as np

from spare_twin.capture.frames import rotation_error_deg


def apply_transform(T: np.ndarray, P: np.ndarray) -> np.ndarray:
    """T (4x4) applied to points P (N, 3)."""
    R = T[:3, :3]
    return P[:, 0:1] * R[:, 0] + P[:, 1:2] * R[:, 1] + P[:, 2:3] * R[:, 2] + T[:3, 3]


def skew(w: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """The 4x4 motion of an update xi = (rotation vector w, translation v): p -> R(w) p + v."""
    w = xi[:3]
    th = float(np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]))
    W = skew(w)
    D = np.eye(4)
    if th < 1e-12:
        D[:3, :3] += W
    else:
        D[:3, :3] += (np.sin(th) / th) * W + ((1.0 - np.cos(th)) / (th * th)) * (W @ W)
    D[:3, 3] = xi[3:]
    return D


def rotation_vector(R: np.ndarray) -> np.ndarray:
    c = np.clip((R[0, 0] + R[1, 1] + R[2, 2] - 1.0) / 2.0, -1.0, 1.0)
    th = float(np.arccos(c))
    a = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if th < 1e-6:
        return a / 2.0
    if th > np.pi - 1e-4:  # near 180 degrees: the axis from the symmetric part
        k = int(np.argmax(np.diag(R)))
        v = (R[:, k] + R[k, :]) / 2.0
        v[k] = np.sqrt(max((R[k, k] + 1.0) / 2.0, 0.0))
        v /= np.linalg.norm(v)
        return th * v * (1.0 if float(np.dot(v, a)) >= 0 else -1.0)
    return a * (th / (2.0 * np.sin(th)))


def invert(T: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -(T[:3, :3].T @ T[:3, 3])
    return out


def normal_equations(J: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """J^T J (k x k) and J^T r of point rows J (N, k), summed in a fixed order (numpy's pairwise sum per
    entry): a BLAS product over the points may split them across threads and add the parts in any order."""
    k = J.shape[1]
    H = np.empty((k, k))
    g = np.empty(k)
    for i in range(k):
        g[i] = np.sum(J[:, i] * r)
        for j in range(i, k):
            H[i, j] = H[j, i] = np.sum(J[:, i] * J[:, j])
    return H, g


def solve_damped(H: np.ndarray, g: np.ndarray) -> np.ndarray:
    """-H^-1 g, lightly damped so that a direction the points do not constrain (a plane's slide) stays put."""
    lam = 1e-9 * max(float(np.trace(H)), 1e-30)
    return -np.linalg.solve(H + lam * np.eye(6), g)


def kabsch(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """(K, 4, 4) rigid motions taking point sets A (K, m, 3) onto B (K, m, 3), least squares (no scale)."""
    ca, cb = A.mean(axis=1), B.mean(axis=1)
    a, b = A - ca[:, None], B - cb[:, None]
    H = (a[:, :, :, None] * b[:, :, None, :]).sum(axis=1)
    U, _, Vt = np.linalg.svd(H)
    V = np.swapaxes(Vt, 1, 2)
    D = np.ones((len(A), 3))
    D[:, 2] = np.sign(np.linalg.det(V @ np.swapaxes(U, 1, 2)))
    R = (V * D[:, None, :]) @ np.swapaxes(U, 1, 2)
    T = np.zeros((len(A), 4, 4))
    T[:, :3, :3] = R
    T[:, :3, 3] = cb - (R * ca[:, None, :]).sum(axis=2)
    T[:, 3, 3] = 1.0
    return T


def turn_deg(A: np.ndarray, B: np.ndarray) -> float:
    """Rotation (degrees) between the rotations of two rigid motions."""
    return rotation_error_deg(A[:3, :3].T @ B[:3, :3])


def axis_angle_deg(A: np.ndarray, B: np.ndarray) -> float:
    """Angle between two cameras' optical axes (degrees)."""
    return float(np.degrees(np.arccos(np.clip(np.dot(A[:3, 2], B[:3, 2]), -1.0, 1.0))))
