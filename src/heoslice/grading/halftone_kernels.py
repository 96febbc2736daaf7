"""Compiled loop of :mod:`heoslice.grading.halftone`: the void-and-cluster ranking of the blue-noise mask (every
process of a blue-noise or error-diffusion slice makes the mask once, in its 8000-odd steps over the tile's
energy: too slow a loop for Python; figures in benchmarks/README.md)."""

from __future__ import annotations

import numpy as np

from heoslice.jit import EXACT, helper, kernel


@helper(EXACT)
def _move(pixel, sign, state, tiled):  # pragma: no cover - compiled
    """Set (sign 1) or clear (sign -1) ``pixel`` (row-major index) of the pattern and add or remove its wrapped
    impulse response (a window of ``tiled``) from the energies; state = (pattern, energy, cluster energy (of the
    set pixels, -inf elsewhere), void energy (of the clear ones, inf elsewhere)), each (n, n)."""
    ones, energy, cluster_energy, void_energy = state
    size = ones.shape[0]
    row, col = pixel // size, pixel % size
    for i in range(size):
        for j in range(size):
            delta = sign * tiled[size - row + i, size - col + j]
            energy[i, j] += delta
            cluster_energy[i, j] += delta
            void_energy[i, j] += delta
    ones[row, col] = sign > 0
    cluster_energy[row, col] = energy[row, col] if sign > 0 else -np.inf
    void_energy[row, col] = np.inf if sign > 0 else energy[row, col]


@helper(EXACT)
def _first_extreme(values, largest):  # pragma: no cover - compiled
    """The row-major index of the first largest (or smallest) of ``values`` ((n, n) float64), as np.argmax."""
    flat = values.ravel()
    best = 0
    for k in range(1, flat.size):
        if (flat[k] > flat[best]) if largest else (flat[k] < flat[best]):
            best = k
    return best


@kernel(EXACT)
def _void_and_cluster(ones, energy, tiled):  # pragma: no cover - compiled
    """The (n, n) int64 ranks of the void-and-cluster mask (see :func:`heoslice.grading.halftone.blue_noise_ranks`)
    from the initial pattern ``ones`` ((n, n) bool), its energy ((n, n) float64) and the wrapped impulse
    response tiled 2 x 2 ((2n, 2n) float64); ``ones`` and ``energy`` are used up."""
    size = ones.shape[0]
    count = size * size
    cluster_energy = np.where(ones, energy, -np.inf)
    void_energy = np.where(ones, np.inf, energy)
    state = (ones, energy, cluster_energy, void_energy)
    for _ in range(count):  # relaxation: far fewer steps in practice
        cluster = _first_extreme(cluster_energy, True)
        _move(cluster, -1.0, state, tiled)
        void = _first_extreme(void_energy, False)
        _move(void, 1.0, state, tiled)
        if void == cluster:
            break
    kept = (ones.copy(), energy.copy(), cluster_energy.copy(), void_energy.copy())
    ranks = np.zeros((size, size), dtype=np.int64)
    placed = 0
    for value in ones.ravel():
        placed += value
    for rank in range(placed - 1, -1, -1):
        cluster = _first_extreme(cluster_energy, True)
        _move(cluster, -1.0, state, tiled)
        ranks[cluster // size, cluster % size] = rank
    ones[:, :], energy[:, :], cluster_energy[:, :], void_energy[:, :] = kept[0], kept[1], kept[2], kept[3]
    for rank in range(placed, count):
        void = _first_extreme(void_energy, False)
        _move(void, 1.0, state, tiled)
        ranks[void // size, void % size] = rank
    return ranks
