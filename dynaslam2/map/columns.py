"""A growable struct of arrays: one row per item, columns of fixed shape and dtype, bulk appends."""

from __future__ import annotations

import numpy as np


class ColumnStore:
    """Rows are ids that stay valid for the store's lifetime; capacity doubles when full.

    Subclasses declare `COLUMNS` as (name, per-row shape, dtype, fill value); every column is an
    attribute of length `capacity`, of which the first `size` rows are in use.
    """

    COLUMNS: tuple[tuple[str, tuple, type, object], ...] = ()

    def __init__(self, capacity: int) -> None:
        self.size = 0
        self.capacity = 0
        self._alloc(capacity)

    def _alloc(self, capacity: int) -> None:
        for name, shape, dtype, fill in self.COLUMNS:
            new = np.full((capacity,) + shape, fill, dtype=dtype)
            if self.capacity:
                new[: self.size] = getattr(self, name)[: self.size]
            setattr(self, name, new)
        self.capacity = capacity

    def _append(self, n: int) -> np.ndarray:
        """Reserve `n` new rows holding the columns' fill values; returns their ids."""
        if self.size + n > self.capacity:
            self._alloc(max(2 * self.capacity, self.size + n))
        ids = np.arange(self.size, self.size + n)
        for name, _, _, fill in self.COLUMNS:
            getattr(self, name)[ids] = fill
        self.size += n
        return ids
