"""Independent reference derivations for the tests (plain numpy, no code shared with rollbot_oc).

``newton_euler`` writes Newton's and Euler's laws for the shell and each point
mass with the contact and internal forces as unknowns, adds the rolling
constraint, and solves the resulting linear system.  It shares no algebra with
the contact-point moment balance that ``rollbot_oc.model.dynamics`` implements (the
paper's closed form), so agreement between the two checks both.
"""

import numpy as np


def _skew(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def quat_matrix(q):
    w, x, y, z = np.asarray(q, float) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def newton_euler(T, omega, masses, M, I, R, gravity, force=np.zeros(3), torque=np.zeros(3)):
    """Solve for (omega_dot, s_ddot, internal forces, ground force) of a rolling shell.

    masses: list of (m, r_body, v_body, a_body) with the prescribed body-frame
    trajectory of each point mass relative to the shell centre.
    Unknowns: s_ddot (3), omega_dot (3), F_q (3 each), N (3).
    Equations: for each mass m (s_ddot + omega_dot x r + h) = F_q + m g;
    shell M s_ddot = -sum F_q + N + M g + f;
    shell I omega_dot = sum r_q x (-F_q) + (-R z) x N + tau;
    rolling s_ddot = omega_dot x (R z).
    """
    nq = len(masses)
    n = 9 + 3 * nq
    A = np.zeros((n, n))
    b = np.zeros(n)
    S, W, N = slice(0, 3), slice(3, 6), slice(6 + 3 * nq, 9 + 3 * nq)
    ez = np.array([0.0, 0.0, 1.0])
    row = 0
    for i, (m, rb, vb, ab) in enumerate(masses):
        r, v, a = T @ rb, T @ vb, T @ ab
        h = np.cross(omega, np.cross(omega, r)) + 2 * np.cross(omega, v) + a
        Fi = slice(6 + 3 * i, 9 + 3 * i)
        A[row:row + 3, S] = m * np.eye(3)
        A[row:row + 3, W] = -m * _skew(r)  # m omega_dot x r = -m [r] omega_dot
        A[row:row + 3, Fi] = -np.eye(3)
        b[row:row + 3] = m * gravity - m * h
        row += 3
        # shell translation and rotation rows are filled below
    shell_t = slice(row, row + 3)
    shell_r = slice(row + 3, row + 6)
    roll = slice(row + 6, row + 9)
    A[shell_t, S] = M * np.eye(3)
    A[shell_t, N] = -np.eye(3)
    b[shell_t] = M * gravity + force
    A[shell_r, W] = I * np.eye(3)
    A[shell_r, N] = _skew(R * ez)  # + (R z) x N on the left
    b[shell_r] = torque
    for i, (m, rb, vb, ab) in enumerate(masses):
        Fi = slice(6 + 3 * i, 9 + 3 * i)
        A[shell_t, Fi] = np.eye(3)
        A[shell_r, Fi] = _skew(T @ rb)  # + r x F on the left
    A[roll, S] = np.eye(3)
    A[roll, W] = _skew(R * ez)  # s_ddot - omega_dot x Rz = s_ddot + [Rz] omega_dot
    sol = np.linalg.solve(A, b)
    forces = [sol[6 + 3 * i: 9 + 3 * i] for i in range(nq)]
    return sol[W], sol[S], forces, sol[N]


def rollbot_mass(theta, theta_dot, theta_ddot, m, r0, phi):
    rho = r0 * np.sin(phi)
    c, s = np.cos(theta), np.sin(theta)
    rb = np.array([rho * c, rho * s, -r0 * np.cos(phi)])
    vb = rho * theta_dot * np.array([-s, c, 0.0])
    ab = rho * (theta_ddot * np.array([-s, c, 0.0]) - theta_dot**2 * np.array([c, s, 0.0]))
    return (m, rb, vb, ab)
