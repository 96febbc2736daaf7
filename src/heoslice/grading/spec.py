"""What a graded slice asks for: the sub-region layout (nozzle D_N, depth, direction; eq. 8) and the materials.

Eq. 8: N_R = int(L_S / D_N) sub-regions, L_S the shortest distance between a family's
starting and ending rings (or a target depth) and D_N the nozzle diameter; sub-region k
(1..N_R) gets the material at r = k / N_R of the distribution function (eq. 1).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

import numpy as np

from heoslice.errors import InputError
from heoslice.material.materials import material_identity

DIRECTIONS = ("in", "out")
#: Where --depth is measured from: each layer's own contour (the paper's offset sub-regions, eq. 8-10), or the
#: model's 3-D surface (the exact point-to-mesh distance, so top and bottom skins are graded like the sides).
DEPTH_FROM = ("layer", "surface")


#: Most sub-regions a family may be cut into (eq. 8's N_R, or --offsets): far more than 8-bit colours can tell apart.
MAX_BANDS = 100_000
#: Nozzle diameters D_N a jetting head can have, mm (a micrometre to a centimetre).
MIN_NOZZLE_MM, MAX_NOZZLE_MM = 1e-3, 10.0


@dataclass(frozen=True)
class RegionSpec:
    """How sub-regions are laid out: nozzle diameter D_N (mm), optional target depth (mm), direction.

    ``direction`` 'in' offsets the outer ring inwards (r = 0 at the outer ring, 1 at the
    inner rings or the depth); 'out' offsets the inner rings outwards (r = 0 at the holes).
    A family without holes is always graded inwards from its outer ring. ``count``
    fixes N_R instead of eq. 8 (the paper's Fig. 3b: 200 offsets). ``depth_from`` 'layer' measures depth
    from each layer's contour (the paper's), 'surface' from the model's 3-D surface (needs ``depth_mm``).
    """

    nozzle_mm: float = 0.2
    depth_mm: float | None = None
    direction: str = "in"
    count: int | None = None
    depth_from: str = "layer"

    def __post_init__(self):
        if self.count is not None and (isinstance(self.count, bool) or int(self.count) != self.count
                                       or self.count < 1):
            raise InputError(f"--offsets: the number of sub-regions must be a whole number >= 1, got {self.count}")
        if self.count is not None and self.count > MAX_BANDS:
            raise InputError(f"--offsets: at most {MAX_BANDS} sub-regions, "
                             f"got {self.count:g}")
        if not (np.isfinite(self.nozzle_mm) and MIN_NOZZLE_MM <= self.nozzle_mm <= MAX_NOZZLE_MM):
            raise InputError(f"--nozzle: nozzle diameter must be between {MIN_NOZZLE_MM:g} and {MAX_NOZZLE_MM:g} mm, "
                             f"got {self.nozzle_mm:g}")
        if self.depth_mm is not None and not (np.isfinite(self.depth_mm) and self.depth_mm > 0):
            raise InputError(f"--depth: target depth must be a positive number of mm, got {self.depth_mm}")
        if self.depth_mm is not None and self.count is None and self.depth_mm / self.nozzle_mm > MAX_BANDS:
            raise InputError(f"--depth: {self.depth_mm:g} mm at a {self.nozzle_mm:g} mm nozzle makes more than "
                             f"{MAX_BANDS} sub-regions (eq. 8)")
        if self.direction not in DIRECTIONS:
            raise InputError(f"--direction: expected 'in' or 'out', got {self.direction!r}")
        if self.depth_from not in DEPTH_FROM:
            raise InputError(f"--depth-from: expected {' or '.join(DEPTH_FROM)}, got {self.depth_from!r}")
        if self.depth_from == "surface" and (self.depth_mm is None or self.direction != "in"):
            raise InputError("--depth-from: 'surface' grades inwards from the model's surface to --depth D mm: "
                             "give --depth (and not --direction out)")


def band_count(length_mm: float, nozzle_mm: float, precision_mm: float = 0.0) -> int:
    """Eq. 8: N_R = int(L_S / D_N), at least 1 (a region thinner than the nozzle is one sub-region).

    ``precision_mm`` is how far L_S may be off through the rounding of the coordinates it was measured
    between (:func:`coordinate_precision`): a ratio within that (or 1e-9) below a whole number counts as it,
    so a 5 mm wall stored in single precision (4.9999996 mm) gives 25 bands at a 0.2 mm nozzle, not 24.
    """
    slack = max(1e-9, precision_mm / nozzle_mm)
    return max(1, int(np.floor(length_mm / nozzle_mm + slack)))


def coordinate_precision(x: np.ndarray, y: np.ndarray) -> float:
    """How far (mm) a distance measured between points with these coordinates ((n,) mm) may be off through
    their rounding: 4 units in the last place of the largest magnitude, in single precision when the
    coordinates are float32 or all exactly float32 values (a float32 mesh: STL, most PLY), else double."""
    if len(x) == 0:
        return 0.0
    single = all(a.dtype == np.float32 or np.array_equal(a.astype(np.float32), a) for a in (x, y))
    epsilon = np.finfo(np.float32 if single else np.float64).eps
    return 4.0 * float(epsilon) * float(max(np.abs(x).max(), np.abs(y).max()))


@dataclass(frozen=True)
class GradeSpec:
    """What a graded slice asks for (``heoslice slice --grade``).

    ``function``: the distribution function (:class:`heoslice.material.DistributionFunction`,
    or None: no gradient, every family keeps its contour's material); ``target``: the
    material M2 reached at r = 1 (eq. 1); ``start``: M1 overriding the contour's
    material (``--from``); ``base``/``second``: the materials a mesh's per-vertex
    material fraction m mixes as (1 - m) base + m second (without it a contour is
    ``base``); ``shells``: (shell number, Material) pairs, a shell's own material
    (its region keeps it, nested shells win); ``mapped``: the table materials a mesh's
    colours were mapped to (:func:`heoslice.material.nearest_materials`), each a channel; ``target_named``: whether
    ``--to`` named the target (else it is the default, which a model's recorded design replaces with its own).
    """

    regions: RegionSpec
    function: object | None
    target: object | None
    start: object | None
    base: object
    second: object | None = None
    shells: tuple = ()
    mapped: tuple = ()
    target_named: bool = True

    def channel_materials(self) -> tuple:
        """The K materials of the droplet masks, without repeats (same name and colour), in a fixed order."""
        found = []
        for material in (self.base, self.second, self.start, self.target, *(m for _, m in self.shells), *self.mapped):
            if material is not None and all(_identity(material) != _identity(m) for m in found):
                found.append(material)
        return tuple(found)

    def with_printer_channels(self, table) -> GradeSpec:
        """This specification with each droplet-mask material that names no printer channel given its table
        material's (``table``: the materials table, channels resolved: the same name and colour), else (a colour
        outside the table) the lowest channel that no table material and no other mask names, in mask order:
        the manifest says where every mask goes, so a print never sends one to the cartridge of a table
        material this stack happens not to use."""
        materials = self.channel_materials()
        listed = {_identity(m): m.channel for m in table if m.channel is not None}
        taken = set(listed.values()) | {m.channel for m in materials if m.channel is not None}
        free = (channel for channel in itertools.count(1) if channel not in taken)
        given = {}
        for material in materials:
            if material.channel is None and _identity(material) not in given:
                channel = listed.get(_identity(material))
                given[_identity(material)] = replace(material, channel=next(free) if channel is None else channel)
        if not given:
            return self

        def assigned(material):
            return None if material is None else given.get(_identity(material), material)

        return replace(self, base=assigned(self.base), second=assigned(self.second), start=assigned(self.start),
                       target=assigned(self.target), shells=tuple((n, assigned(m)) for n, m in self.shells),
                       mapped=tuple(assigned(m) for m in self.mapped))

    def channel_index(self, material) -> int:
        """The index of ``material`` (by name and colour) among :meth:`channel_materials`: its column of a
        (..., K) mix and its plane of the droplet masks. Raises ValueError for a material not among them."""
        identities = [_identity(m) for m in self.channel_materials()]
        try:
            return identities.index(_identity(material))
        except ValueError:
            raise ValueError(f"material {material.name!r} {tuple(material.color)} is not one of the droplet "
                             f"masks' materials") from None


def _identity(material) -> tuple:
    """What makes two materials the same droplet-mask material (:func:`heoslice.material.material_identity`)."""
    return material_identity(material)
