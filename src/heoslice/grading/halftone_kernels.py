"""Compiled loop of :mod:`heoslice.grading.halftone`: the void-and-cluster ranking of the blue-noise mask (every
process of a blue-noise or error-diffusion slice makes the mask once, in its 8000-odd steps over the tile's
energy: too slow a loop for Python; figures in benchmarks/README.md)."""

from __future__ import annotations

import numpy as np

from heoslice.jit import EXACT, helper, kernel


@helper(EXACT)
def _move(pixel, sign, state, tiled, reach):  # pragma: no cover - compiled
    """Set (sign 1) or clear (sign -1) ``pixel`` (row-major index) of the pattern and add or remove its wrapped
    impulse response (a window of ``tiled``) from the energies; state = (pattern, energy, cluster energy (of the
    set pixels, -inf elsewhere), void energy (of the clear ones, inf elsewhere)), each (n, n), and the column of
    each row's first largest cluster energy and first smallest void energy ((n,) int64 each). Only the rows and
    columns within ``reach`` of it (wrapped; :func:`_reach`) are touched: the response is exactly 0 beyond, and
    adding 0 leaves an energy as it is."""
    ones, energy, cluster_energy, void_energy, cluster_best, void_best = state
    size = ones.shape[0]
    row, col = pixel // size, pixel % size
    span = min(2 * reach + 1, size)
    for a in range(span):
        i = (row - reach + a) % size
        for b in range(span):
            j = (col - reach + b) % size
            delta = sign * tiled[size - row + i, size - col + j]
            energy[i, j] += delta
            cluster_energy[i, j] += delta
            void_energy[i, j] += delta
    ones[row, col] = sign > 0
    cluster_energy[row, col] = energy[row, col] if sign > 0 else -np.inf
    void_energy[row, col] = np.inf if sign > 0 else energy[row, col]
    for a in range(span):
        i = (row - reach + a) % size
        cluster_best[i] = _row_extreme(cluster_energy[i], True)
        void_best[i] = _row_extreme(void_energy[i], False)


@helper(EXACT)
def _reach(tiled):  # pragma: no cover - compiled
    """The largest wrapped row or column distance from pixel (0, 0) at which the impulse response (the first
    (n, n) quarter of ``tiled``) is not 0."""
    size = tiled.shape[0] // 2
    reach = 0
    for a in range(size):
        for b in range(size):
            if tiled[a, b] != 0.0:
                reach = max(reach, min(a, size - a), min(b, size - b))
    return reach


@helper(EXACT)
def _row_extreme(values, largest):  # pragma: no cover - compiled
    """The index of the first largest (or smallest) of ``values`` ((n,) float64), as np.argmax."""
    best = 0
    for k in range(1, values.size):
        if (values[k] > values[best]) if largest else (values[k] < values[best]):
            best = k
    return best


@helper(EXACT)
def _first_extreme(values, best, largest):  # pragma: no cover - compiled
    """The row-major index of the first largest (or smallest) of ``values`` ((n, n) float64), as np.argmax, from
    the column of each row's first one (``best``, (n,) int64): the first row whose one is the extreme."""
    top = 0
    for i in range(1, values.shape[0]):
        here, there = values[i, best[i]], values[top, best[top]]
        if (here > there) if largest else (here < there):
            top = i
    return top * values.shape[1] + best[top]


@kernel(EXACT)
def _void_and_cluster(ones, energy, tiled):  # pragma: no cover - compiled
    """The (n, n) int64 ranks of the void-and-cluster mask (see :func:`heoslice.grading.halftone.blue_noise_ranks`)
    from the initial pattern ``ones`` ((n, n) bool), its energy ((n, n) float64) and the wrapped impulse
    response tiled 2 x 2 ((2n, 2n) float64); ``ones`` and ``energy`` are used up."""
    size = ones.shape[0]
    count = size * size
    cluster_energy = np.where(ones, energy, -np.inf)
    void_energy = np.where(ones, np.inf, energy)
    cluster_best = np.array([_row_extreme(cluster_energy[i], True) for i in range(size)])
    void_best = np.array([_row_extreme(void_energy[i], False) for i in range(size)])
    state = (ones, energy, cluster_energy, void_energy, cluster_best, void_best)
    reach = _reach(tiled)
    for _ in range(count):  # relaxation: far fewer steps in practice
        cluster = _first_extreme(cluster_energy, cluster_best, True)
        _move(cluster, -1.0, state, tiled, reach)
        void = _first_extreme(void_energy, void_best, False)
        _move(void, 1.0, state, tiled, reach)
        if void == cluster:
            break
    kept = (ones.copy(), energy.copy(), cluster_energy.copy(), void_energy.copy(), cluster_best.copy(),
            void_best.copy())
    ranks = np.zeros((size, size), dtype=np.int64)
    placed = 0
    for value in ones.ravel():
        placed += value
    for rank in range(placed - 1, -1, -1):
        cluster = _first_extreme(cluster_energy, cluster_best, True)
        _move(cluster, -1.0, state, tiled, reach)
        ranks[cluster // size, cluster % size] = rank
    ones[:, :], energy[:, :], cluster_energy[:, :], void_energy[:, :] = kept[0], kept[1], kept[2], kept[3]
    cluster_best[:], void_best[:] = kept[4], kept[5]
    for rank in range(placed, count):
        void = _first_extreme(void_energy, void_best, False)
        _move(void, 1.0, state, tiled, reach)
        ranks[void // size, void % size] = rank
    return ranks
