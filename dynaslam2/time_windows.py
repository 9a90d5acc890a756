"""Time windows over differences of timestamps.

Timestamps come from text (times.txt) or from frame counts, and the difference of two of them rounds to either side
of a window that is a multiple of the frame period (9.8 - 9.0 = 0.8000000000000007 > 0.8, while 1.6 - 0.8 = 0.8):
the same gap fell inside a window at some times of a sequence and outside it at others (crossing s49: a person
hidden for exactly join_max_gap_s at t = 9.0-9.8 s was given a new track). Every window is taken with a tolerance
far below any frame period."""
from __future__ import annotations

import numpy as np

TOLERANCE_S = 1e-6


def within(dt_s: float | np.ndarray, window_s: float | np.ndarray) -> bool | np.ndarray:
    """`dt_s <= window_s` up to TOLERANCE_S (floats, or numpy arrays elementwise)."""
    return dt_s <= window_s + TOLERANCE_S
