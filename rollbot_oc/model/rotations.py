"""Rotation helpers: skew matrices and unit quaternions, scalar first (w, x, y, z).

A quaternion ``q`` here always maps body-frame vectors to the ground frame:
``v_ground = quat_to_matrix(q) @ v_body``.  The symbolic helpers accept CasADi
SX/MX/DM as well as plain numbers; the ``*_np`` helpers are plain numpy, for
building states and reading results.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from rollbot_oc.core.reproducible import norm

__all__ = [
    "skew", "quat_to_matrix", "quat_multiply", "quat_derivative",
    "quat_multiply_np", "rot_x_np", "rot_y_np", "rot_z_np", "matrix_to_quat_np", "quat_to_matrix_np",
]


def skew(v):
    """Skew-symmetric matrix ``[v]`` with ``[v] @ a = v x a`` (CasADi)."""
    return ca.vertcat(
        ca.horzcat(0, -v[2], v[1]),
        ca.horzcat(v[2], 0, -v[0]),
        ca.horzcat(-v[1], v[0], 0),
    )


def quat_to_matrix(q):
    """Rotation matrix of quaternion ``q = (w, x, y, z)`` (CasADi).

    Divides by ``|q|^2`` so that a quaternion that has drifted slightly from
    unit norm still gives an orthogonal matrix to first order.
    """
    w, x, y, z = q[0], q[1], q[2], q[3]
    n = w * w + x * x + y * y + z * z
    s = 2.0 / n
    return ca.vertcat(
        ca.horzcat(1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)),
        ca.horzcat(s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w)),
        ca.horzcat(s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y)),
    )


def quat_multiply(a, b):
    """Hamilton product ``a * b`` of two quaternions (CasADi)."""
    aw, av = a[0], ca.vertcat(a[1], a[2], a[3])
    bw, bv = b[0], ca.vertcat(b[1], b[2], b[3])
    return ca.vertcat(aw * bw - ca.dot(av, bv), aw * bv + bw * av + ca.cross(av, bv))


def quat_derivative(q, omega):
    """Time derivative of ``q`` for angular velocity ``omega`` given in the ground frame."""
    return 0.5 * quat_multiply(ca.vertcat(0, omega), q)


def quat_multiply_np(a, b) -> np.ndarray:
    """Hamilton product ``a * b`` of two quaternions (numpy; plain arithmetic, it runs every control step)."""
    aw, ax, ay, az = (float(v) for v in a)
    bw, bx, by, bz = (float(v) for v in b)
    return np.array([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ])


def rot_x_np(angle: float) -> np.ndarray:
    """Rotation matrix about x by ``angle`` (rad)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y_np(angle: float) -> np.ndarray:
    """Rotation matrix about y by ``angle`` (rad)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z_np(angle: float) -> np.ndarray:
    """Rotation matrix about z by ``angle`` (rad)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def quat_to_matrix_np(q) -> np.ndarray:
    """Rotation matrix of a quaternion (numpy, normalises first)."""
    return np.array(ca.DM(quat_to_matrix(ca.DM(np.asarray(q, float)))))


def matrix_to_quat_np(T) -> np.ndarray:
    """Unit quaternion (w >= 0) of a rotation matrix (numpy; Shepperd's method)."""
    T = np.asarray(T, float)
    trace = np.trace(T)
    if trace > max(T[0, 0], T[1, 1], T[2, 2]):
        w = 0.5 * np.sqrt(1.0 + trace)
        q = [w, (T[2, 1] - T[1, 2]) / (4 * w), (T[0, 2] - T[2, 0]) / (4 * w), (T[1, 0] - T[0, 1]) / (4 * w)]
    else:
        i = int(np.argmax(np.diag(T)))
        j, k = (i + 1) % 3, (i + 2) % 3
        v = 0.5 * np.sqrt(1.0 + T[i, i] - T[j, j] - T[k, k])
        q = [0.0, 0.0, 0.0, 0.0]
        q[0] = (T[k, j] - T[j, k]) / (4 * v)
        q[1 + i] = v
        q[1 + j] = (T[j, i] + T[i, j]) / (4 * v)
        q[1 + k] = (T[k, i] + T[i, k]) / (4 * v)
    q = np.array(q)
    q /= norm(q)
    return q if q[0] >= 0 else -q
