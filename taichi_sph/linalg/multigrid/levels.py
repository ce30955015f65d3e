"""The coarse levels of the cell multigrid (linalg/multigrid/) as boxes of cells: level 1 is the neighbour
search's cell grid, each next level merges 2^dim cells (an axis stops halving where a periodic axis would drop
below 3 cells), down to at most COARSEST_CELLS cells."""

import math
from dataclasses import dataclass

# stop coarsening at this many cells (empty ones included); the coarsest level gets Gauss-Seidel sweeps
COARSEST_CELLS = 64


@dataclass(frozen=True)
class GridLevel:
    """One coarse level: a box of cells (last axis fastest), stored at `offset` in the flat arrays."""

    n: tuple[int, ...]
    periodic: tuple[bool, ...]
    offset: int
    factor: tuple[int, ...]  # cells of this level merged per axis into one of the next (1 or 2)

    @property
    def count(self) -> int:
        return math.prod(self.n)

    @property
    def strides(self) -> tuple[int, ...]:
        s = [1] * len(self.n)
        for d in range(len(self.n) - 2, -1, -1):
            s[d] = s[d + 1] * self.n[d + 1]
        return tuple(s)


def coarsening_factors(n: tuple[int, ...], periodic: tuple[bool, ...]) -> tuple[int, ...]:
    """Per axis 2 where the axis can halve (a periodic one keeps >= 3 cells, so that the 3-wide stencil
    never names one cell twice), else 1."""
    return tuple(2 if (n_d >= 6 if per else n_d >= 2) else 1 for n_d, per in zip(n, periodic))


def grid_levels(n_cells: tuple[int, ...], periodic: tuple[bool, ...]) -> list[GridLevel]:
    """Level 1 (the neighbour cells) and its coarsenings down to <= COARSEST_CELLS cells."""
    levels: list[GridLevel] = []
    n, offset = tuple(n_cells), 0
    while True:
        f = coarsening_factors(n, periodic)
        last = math.prod(n) <= COARSEST_CELLS or all(x == 1 for x in f)
        levels.append(GridLevel(n, periodic, offset, (1,) * len(n) if last else f))
        if last:
            return levels
        offset += math.prod(n)
        n = tuple((n_d + f_d - 1) // f_d for n_d, f_d in zip(n, f))
