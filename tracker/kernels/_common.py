"""Shared pieces of the compiled per-frame kernels: array signatures and scalar angle helpers.

Each kernel module of :mod:`tracker.kernels` sits beside the numpy stage it speeds up
(``kernels/cost.py`` ↔ ``tracker/cost.py`` and so on); see ``tracker/kernels/__init__.py``.
"""

from __future__ import annotations

import math

import numba

_PI = math.pi
_TWO_PI = 2.0 * math.pi
_HALF_PI = 0.5 * math.pi


# Kernel signatures: inputs are read-only arrays of any layout (numba accepts writable and
# strided arrays for them too), outputs updated in place are writable.
_f8, _i8 = numba.float64, numba.int64
_F1, _F2, _F3, _F4 = (numba.types.Array(_f8, n, "A", readonly=True) for n in (1, 2, 3, 4))
_I1 = numba.types.Array(_i8, 1, "A", readonly=True)
_F1_OUT, _F2_OUT = numba.types.Array(_f8, 1, "A"), numba.types.Array(_f8, 2, "A")
_F3_OUT, _F4_OUT = numba.types.Array(_f8, 3, "A"), numba.types.Array(_f8, 4, "A")
_I1_OUT = numba.types.Array(_i8, 1, "A")
_S1 = numba.types.Array(numba.int8, 1, "A", readonly=True)
_B1 = numba.types.Array(numba.boolean, 1, "A", readonly=True)


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _wrap(a: float) -> float:  # pragma: no cover (compiled)
    """tracker.geometry.wrap_angle of one value: (-pi, pi], in-range values bit-for-bit."""
    if abs(a) < _PI or not (a > _PI or a <= -_PI):  # in range (or NaN): unchanged
        return a
    wrapped = (a + _PI) % _TWO_PI - _PI  # Python's float % takes the divisor's sign, as np.mod
    return wrapped + _TWO_PI if wrapped <= -_PI else wrapped


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _align(measured: float, predicted: float) -> float:  # pragma: no cover (compiled)
    """tracker.kalman.align_heading of one value."""
    if abs(_wrap(measured - predicted)) > _HALF_PI:
        return _wrap(measured + _PI)
    return _wrap(measured)
