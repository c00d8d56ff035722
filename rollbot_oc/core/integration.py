"""The fixed-step integrator the plant, the estimators and the optimal-control layer share: classical RK4."""

from __future__ import annotations

__all__ = ["rk4"]


def rk4(rhs, x, h, substeps: int, *args):
    """``substeps`` classical Runge-Kutta steps of ``x' = rhs(x, *args)`` over a time ``h`` (symbolic or numeric).

    The arguments ``args`` (input, parameters, ...) are held over the whole interval.
    """
    step = h / substeps
    for _ in range(substeps):
        k1 = rhs(x, *args)
        k2 = rhs(x + step / 2 * k1, *args)
        k3 = rhs(x + step / 2 * k2, *args)
        k4 = rhs(x + step * k3, *args)
        x = x + step / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x
