"""Each label's boundary, reconstructed smoothly between voxel centres, as a field that is positive inside.

A label's voxels (a 0/1 mask) are blurred with a Gaussian of sigma voxels and the blurred value s is
turned into a distance-like value sigma * probit(s) (for a flat boundary, exactly the signed distance in
voxels: the blur of a step is the normal distribution's CDF). The blur's shift of a curved surface, sigma^2
/ 2 times its curvature, is added back (the curvature measured on the field itself, smoothed). Sigma
follows the label's thickness (:func:`label_smooth`): a wide blur averages away the voxels' stair steps over a
large structure, a narrow one keeps a thin structure's shape. Its zero level is then moved so that the
region the field marks inside, trilinearly interpolated, holds exactly the label's voxel volume: the
blur's shrinking of curved surfaces is undone and a label of one voxel keeps one voxel's volume, centred
on its voxel. Last, the field is held within BAND voxels of the voxels' own signed distance (that of the
surface half-way between a label's voxel centres and its neighbours', where marching cubes puts it), so the
smooth surface keeps to the voxels even at thin parts and at the sharp edges a scan's field of view cuts
(where a wide blur would round them off or lose them), and its volume-preserving level is set again (which
may move it a little further where the band held it: tests/test_volume_mesh_route.py measures the result
against marching cubes). Fields are computed once per label on the label's bounding box (padded by the
blur's reach), so their memory follows the labels' sizes, not the volume's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: The blur, voxels (sigma): SMOOTH_PER_RADIUS times the label's largest inscribed radius (voxels), within
#: MIN_SMOOTH .. MAX_SMOOTH; the accuracy of tests/test_volume_accuracy.py's phantoms rests on these.
SMOOTH_PER_RADIUS, MIN_SMOOTH, MAX_SMOOTH = 0.3, 1.5, 3.0
#: The blur's reach, sigmas: the padding of a label's box.
REACH_SIGMAS = 3.0
#: Blurred values are clipped to [CLIP, 1 - CLIP] before the probit (far from a label its field saturates).
CLIP = 1e-6
#: The value of a label's field beyond its box: farther outside than any computed value.
FAR_OUTSIDE = -1e3
#: Voxels: how far the smooth field may depart from the voxels' own signed distance (see the module's note).
BAND = 0.3
#: Samples inside a label wanted to settle its zero level (the supersampling per axis adapts, 2 to 4).
LEVEL_SAMPLES_INSIDE = 20_000


@dataclass(frozen=True)
class LabelField:
    """One label's field on its padded box of the oriented grid (z, y, x along the printer's axes).

    start: (3,) int64, the box's first index in the oriented grid (it may start before the grid: padding);
    values: (nz, ny, nx) float32, voxels, positive inside; voxels: the label's voxel count; radius: voxels, its
    largest inscribed radius (the largest value of its Euclidean distance transform: 1 for a one-voxel line).
    """

    start: np.ndarray
    values: np.ndarray
    voxels: int
    radius: float

    @property
    def stop(self) -> np.ndarray:
        return self.start + np.array(self.values.shape)


def padding(smooth: float) -> int:
    """Voxels of padding around a label's box: the blur's reach plus one."""
    return int(np.ceil(REACH_SIGMAS * smooth)) + 1


def padded_crop(array: np.ndarray, box: tuple[slice, ...], pad: int) -> tuple[np.ndarray, np.ndarray]:
    """The part of ``array`` inside ``box`` grown by ``pad`` on every side (zeros beyond the array), and the
    grown box's start ((3,) int64, possibly negative)."""
    start = np.array([piece.start - pad for piece in box], dtype=np.int64)
    stop = np.array([piece.stop + pad for piece in box], dtype=np.int64)
    inner_start = np.maximum(start, 0)
    inner_stop = np.minimum(stop, array.shape)
    crop = array[tuple(slice(a, b) for a, b in zip(inner_start, inner_stop))]
    widths = [(int(a - s), int(e - b)) for s, a, b, e in zip(start, inner_start, inner_stop, stop)]
    return np.pad(crop, widths), start


def supersampled(values: np.ndarray, factor: int) -> np.ndarray:
    """``values`` ((nz, ny, nx)) interpolated linearly at ``factor`` evenly spaced points across each voxel
    along every axis (edges clamped): shape (nz f, ny f, nx f), the trilinear field sampled inside each voxel."""
    out = values
    for axis in range(3):
        ahead = np.concatenate([np.delete(out, 0, axis), np.take(out, [-1], axis)], axis=axis)
        behind = np.concatenate([np.take(out, [0], axis), np.delete(out, -1, axis)], axis=axis)
        pieces = []
        for m in range(factor):
            t = np.float32((m + 0.5) / factor - 0.5)
            pieces.append((1 - abs(t)) * out + abs(t) * (ahead if t > 0 else behind))
        out = np.stack(pieces, axis=axis + 1).reshape(
            [n * (factor if k == axis else 1) for k, n in enumerate(out.shape)])
    return out


def _samples_near(values: np.ndarray, factor: int, low: float, taken: np.ndarray | None = None) -> np.ndarray:
    """The trilinear samples of ``values`` at ``factor`` evenly spaced points across each voxel (as
    :func:`supersampled`), taken only around voxels with a neighbour above ``low`` (elsewhere every sample is at
    most ``low``), less those where ``taken`` (a field on the same box) is positive: (n,) float32. Each voxel's
    samples are a separable weighting of its 3 x 3 x 3 neighbours (edges clamped)."""
    from scipy import ndimage

    chosen = np.argwhere(ndimage.maximum_filter(values, size=3, mode="nearest") > low)
    if not len(chosen):
        return np.zeros(0, np.float32)
    index = [np.clip(chosen[:, axis, None] + np.arange(-1, 2), 0, values.shape[axis] - 1) for axis in range(3)]
    offsets = (np.arange(factor) + 0.5) / factor - 0.5
    weights = np.zeros((factor, 3), dtype=np.float32)
    weights[:, 1] = 1.0 - np.abs(offsets)
    weights[:, 0] = np.maximum(-offsets, 0.0)
    weights[:, 2] = np.maximum(offsets, 0.0)

    def sampled(field: np.ndarray, rows=slice(None)) -> np.ndarray:
        near = field[index[0][rows, :, None, None], index[1][rows, None, :, None], index[2][rows, None, None, :]]
        return np.einsum("nabc,ia,jb,kc->nijk", near, weights, weights, weights, optimize=True)

    flat = sampled(values)
    if taken is None:
        return flat.ravel()
    reached = np.flatnonzero(ndimage.maximum_filter(taken, size=3, mode="nearest")[tuple(chosen.T)] > 0)
    keep = np.ones(flat.shape, dtype=bool)
    keep[reached] = sampled(taken, reached) <= 0
    return flat[keep]


def level_offset(values: np.ndarray, voxels: int, taken: np.ndarray | None = None) -> float:
    """The value whose upper level set of ``values`` ((nz, ny, nx) float32), trilinearly interpolated and
    sampled k times per voxel along each axis (k from 2 to 4, enough samples inside even a one-voxel label),
    holds ``voxels`` voxels: the volume-preserving zero level. Only samples near the label are made (those
    above ``low``, lowered until they hold the volume), so a thin label with a large box stays cheap. Samples
    where ``taken`` (another field on the same box: the labels that win over this one) is positive do not
    count, so the level set holds the volume outside them."""
    factor = int(np.clip(np.ceil((LEVEL_SAMPLES_INSIDE / max(voxels, 1)) ** (1 / 3)), 2, 4))
    wanted = int(max(1, round(voxels * factor ** 3)))
    for low in (-1.0, -3.0, -np.inf):
        if np.isfinite(low):
            flat = _samples_near(values, factor, low, taken)
        else:
            flat = supersampled(values, factor).ravel()
            flat = flat if taken is None else flat[supersampled(taken, factor).ravel() <= 0]
        if np.count_nonzero(flat > low) >= wanted or not np.isfinite(low):
            wanted = min(wanted, flat.size)
            return float(-np.partition(-flat, wanted - 1)[wanted - 1]) if wanted else 0.0
    raise AssertionError("unreachable")


def curvature_shift(values: np.ndarray, smooth: float) -> np.ndarray:
    """(nz, ny, nx) float32: what a blur of ``smooth`` voxels moved each point of a level surface of ``values``
    inwards, sigma^2 / 2 times the sum of its principal curvatures (-div of the unit normal): added back, a
    sphere keeps its radius and a saddle its shape (the blur shrinks convex parts, grows concave ones)."""
    gradient = np.gradient(values)
    norm = np.sqrt(sum(g * g for g in gradient)) + np.float32(1e-6)
    divergence = sum(np.gradient(g / norm, axis=axis) for axis, g in enumerate(gradient))
    from scipy import ndimage

    divergence = ndimage.gaussian_filter(divergence, smooth, mode="nearest", truncate=REACH_SIGMAS)
    return np.clip(-0.5 * smooth * smooth * divergence, -smooth, smooth).astype(np.float32)


def voxel_distance(mask: np.ndarray, depth: np.ndarray | None = None) -> np.ndarray:
    """(nz, ny, nx) float32, voxels: the signed distance of each voxel centre of a 0/1 ``mask`` to the surface
    half-way between the label's voxels and the others (positive inside: a voxel with a face neighbour outside
    is 0.5 inside), from Euclidean distance transforms of the mask (``depth``, when already made) and of its
    complement."""
    from scipy import ndimage

    inside = ndimage.distance_transform_edt(mask) if depth is None else depth
    outside = ndimage.distance_transform_edt(~mask)
    return np.where(mask, inside - 0.5, 0.5 - outside).astype(np.float32)


def smooth_field(mask: np.ndarray, voxels: int, smooth: float, depth: np.ndarray | None = None) -> np.ndarray:
    """(nz, ny, nx) float32 field of a padded 0/1 ``mask`` of ``voxels`` voxels: sigma * probit of the blurred
    mask, less its volume-preserving level (:func:`level_offset`), held within BAND of :func:`voxel_distance`
    (``depth``: the mask's distance transform, when already made), its level then set again (``smooth`` 0:
    the voxels as blocks, +-0.5)."""
    from scipy import ndimage, special

    if smooth <= 0:
        values = np.where(mask, 0.5, -0.5).astype(np.float32)
        return values - np.float32(level_offset(values, voxels))
    blurred = ndimage.gaussian_filter(mask.astype(np.float32), smooth, mode="constant", truncate=REACH_SIGMAS)
    values = (special.ndtri(np.clip(blurred, CLIP, 1 - CLIP)) * smooth).astype(np.float32)
    values += curvature_shift(values, smooth)
    values -= np.float32(level_offset(values, voxels))
    distance = voxel_distance(mask.astype(bool), depth)
    values = np.clip(values, distance - np.float32(BAND), distance + np.float32(BAND))
    return values - np.float32(level_offset(values, voxels))


def label_smooth(mask: np.ndarray, depth: np.ndarray | None = None) -> float:
    """The blur (sigma, voxels) of a label's 0/1 ``mask``: SMOOTH_PER_RADIUS x its largest inscribed radius
    (the largest value of its Euclidean distance transform, ``depth`` when already made), within MIN_SMOOTH ..
    MAX_SMOOTH."""
    from scipy import ndimage

    if depth is None:
        depth = ndimage.distance_transform_edt(mask) if mask.any() else np.zeros(1)
    return float(np.clip(SMOOTH_PER_RADIUS * float(depth.max()), MIN_SMOOTH, MAX_SMOOTH))


def _field_of(crop: np.ndarray, start: np.ndarray, smooth: float | None) -> LabelField:
    """The LabelField of a padded 0/1 mask starting at ``start``, blurred by ``smooth`` (None: :func:`label_smooth`)."""
    from scipy import ndimage

    voxels = int(np.count_nonzero(crop))
    depth = ndimage.distance_transform_edt(crop)
    sigma = label_smooth(crop, depth) if smooth is None else smooth
    return LabelField(start, smooth_field(crop, voxels, sigma, depth), voxels, float(depth.max(initial=0.0)))


def label_field(oriented: np.ndarray, value: int, box: tuple[slice, ...], smooth: float | None = None) -> LabelField:
    """The :class:`LabelField` of the voxels equal to ``value`` in ``oriented`` (a label array along the
    printer's axes) within ``box`` (their bounding box); ``smooth`` fixes the blur (None: by thickness)."""
    crop, start = padded_crop(oriented, box, padding(MAX_SMOOTH if smooth is None else smooth))
    return _field_of(crop == value, start, smooth)
