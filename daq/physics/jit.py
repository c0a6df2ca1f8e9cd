"""The one way this project compiles numerical code.

``error_model="numpy"`` lets a float division by zero give inf/nan instead of
raising, which removes a branch and a Python-exception path from every
division in the hot loop (the rhs runs ~10^6 times per simulated run).
Helpers are inlined at numba-IR level so scalar code fuses into one function.
"""

from __future__ import annotations

from numba import njit

kernel = njit(cache=True, error_model="numpy")
helper = njit(cache=True, error_model="numpy", inline="always")
