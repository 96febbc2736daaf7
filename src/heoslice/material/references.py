"""Reference features (a plane, point, axis or surface) and each point's distance to one (paper section II.B).

A material distribution measures the minimum distance of every point to a reference
feature and normalises it to r in [0, 1] (:func:`normalise`). Every kind of reference
is one row of :data:`REFERENCES`: the options it takes, how its defaults resolve
against the model, its distance and how it is written. Points are (n, 3) float arrays
in mm. Errors name the parameter of :func:`make_reference` (``kind``, ``at``,
``normal``, ``direction``, ``surface``) or of :func:`normalise` (``r_range``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from heoslice.errors import InputError, shown
from heoslice.material.functions import DistributionFunction, evaluate, finite
from heoslice.mesh import MAX_COORDINATE
from heoslice.material.surface import (
    SurfaceIndex,
    build_surface_index,
    surface_distance,
)


@dataclass(frozen=True, eq=False)
class Reference:
    """A reference feature with every default resolved.

    kind: a key of :data:`REFERENCES`. point: (3,) mm, a point of the plane or axis, or
    the point itself. direction: (3,) unit normal of the plane or direction of the axis
    (None otherwise). surface: the indexed reference surface for kind 'surface'.
    """

    kind: str
    point: tuple[float, float, float] | None = None
    direction: tuple[float, float, float] | None = None
    surface: SurfaceIndex | None = None

    def describe(self) -> str:
        """One line for logs and PLY comments."""
        return REFERENCES[self.kind].written(self)


def _text(vector) -> str:
    return "(" + ", ".join(f"{x + 0.0:.6g}" for x in np.round(vector, 9)) + ")"


def _vector(name: str, value, unit: bool = False) -> np.ndarray:
    """(3,) float64 from three numbers (a unit vector when ``unit``); InputError naming the parameter."""
    try:
        vector = np.asarray(value, dtype=np.float64).reshape(3)
    except (TypeError, ValueError):
        raise InputError(f"{name}: must be three numbers x,y,z, got {shown(value)}") from None
    if not np.isfinite(vector).all():
        raise InputError(f"{name}: must be finite, got {shown(value)}")
    if unit:
        largest = float(np.abs(vector).max())
        if largest == 0.0:
            raise InputError(f"{name}: must not be the zero vector")
        vector = vector / largest  # scaled first, so that no square overflows (1e308,1e308,0 is a direction)
        return vector / float(np.linalg.norm(vector))
    if float(np.abs(vector).max()) > MAX_COORDINATE:
        raise InputError(f"{name}: coordinates must be within +-{MAX_COORDINATE:g} mm, got {shown(value)}")
    return vector


def _centre(vertices: np.ndarray) -> np.ndarray:
    return (vertices.min(axis=0) + vertices.max(axis=0)) / 2.0


def _resolve_plane(vertices, faces, at, normal, direction, surface) -> Reference:
    n = _vector("normal", (0.0, 0.0, 1.0) if normal is None else normal, unit=True)
    p = vertices[np.argmin(vertices @ n)] if at is None else _vector("at", at)
    return Reference("plane", tuple(map(float, p)), tuple(map(float, n)))


def _resolve_point(vertices, faces, at, normal, direction, surface) -> Reference:
    p = _centre(vertices) if at is None else _vector("at", at)
    return Reference("point", tuple(map(float, p)))


def _resolve_axis(vertices, faces, at, normal, direction, surface) -> Reference:
    u = _vector("direction", (0.0, 0.0, 1.0) if direction is None else direction, unit=True)
    p = _centre(vertices) if at is None else _vector("at", at)
    return Reference("axis", tuple(map(float, p)), tuple(map(float, u)))


def _resolve_surface(vertices, faces, at, normal, direction, surface) -> Reference:
    if surface is None:
        if faces is None:
            raise InputError("surface: a surface reference on the model itself needs the model's faces")
        surface = (vertices, faces)
    return Reference("surface", surface=build_surface_index(*surface))


def _offsets(reference: Reference, x, y, z) -> tuple:
    """The offsets from the reference's point along x, y and z (arrays that broadcast together, mm)."""
    p = reference.point
    return x - p[0], y - p[1], z - p[2]


def _plane_at(reference: Reference, x, y, z) -> np.ndarray:
    """|(q - p) . n| at points q = (x, y, z) (arrays that broadcast, mm): the distance to the plane; a coordinate
    the normal has no component along is not read (a level plane's distance over a layer is one number)."""
    terms = [offset * n for offset, n in zip(_offsets(reference, x, y, z), reference.direction) if n != 0.0]
    return np.abs(sum(terms[1:], terms[0]))


def _point_at(reference: Reference, x, y, z) -> np.ndarray:
    """|q - p| at points q = (x, y, z) (arrays that broadcast, mm): the distance to the point."""
    ox, oy, oz = _offsets(reference, x, y, z)
    square = (ox * ox + oz * oz) + oy * oy  # over a layer's grid: one (h, w) sum, the others a row's
    return np.sqrt(square, out=square) if isinstance(square, np.ndarray) else np.sqrt(square)


def _axis_at(reference: Reference, x, y, z) -> np.ndarray:
    """|(q - p) - ((q - p) . u) u| at points q = (x, y, z) (arrays that broadcast, mm): the distance to the axis."""
    ox, oy, oz = _offsets(reference, x, y, z)
    u = reference.direction
    along = ox * u[0] + oy * u[1] + oz * u[2]
    ax, ay, az = ox - along * u[0], oy - along * u[1], oz - along * u[2]
    return np.sqrt(ax * ax + ay * ay + az * az)


def _plane_square(reference: Reference, z: float) -> tuple[float, ...]:
    """The squared distance to a plane at height z as (A, B, C, D, E, F) of :func:`grid_square`: (n . o)^2."""
    nx, ny, nz = reference.direction
    w = nz * (z - reference.point[2])
    return nx * nx, 2 * nx * ny, ny * ny, 2 * nx * w, 2 * ny * w, w * w


def _point_square(reference: Reference, z: float) -> tuple[float, ...]:
    """The squared distance to a point at height z as (A, B, C, D, E, F) of :func:`grid_square`: |o|^2."""
    w = z - reference.point[2]
    return 1.0, 0.0, 1.0, 0.0, 0.0, w * w


def _axis_square(reference: Reference, z: float) -> tuple[float, ...]:
    """The squared distance to an axis at height z as (A, B, C, D, E, F) of :func:`grid_square`:
    |o|^2 - (o . u)^2."""
    ux, uy, uz = reference.direction
    oz = z - reference.point[2]
    w = uz * oz
    return 1 - ux * ux, -2 * ux * uy, 1 - uy * uy, -2 * ux * w, -2 * uy * w, oz * oz - w * w


def _columns(at: Callable) -> Callable:
    """A closed-form distance at (x, y, z) arrays as a distance at points (n, 3)."""
    return lambda reference, points, progress: at(reference, points[:, 0], points[:, 1], points[:, 2])


def _surface_distance(reference: Reference, points: np.ndarray, progress) -> np.ndarray:
    return surface_distance(points, reference.surface, progress=progress)


@dataclass(frozen=True)
class ReferenceKind:
    """One kind of reference feature.

    options: the geometry parameters of :func:`make_reference` it takes; resolve(vertices,
    faces, at, normal, direction, surface) -> Reference with the defaults filled in;
    distance(reference, points (n, 3), progress) -> (n,) mm; written(reference) -> text;
    closed_form(reference, x, y, z) -> the distance at coordinate arrays that broadcast together (None for
    a surface, which is searched); square(reference, z) -> the squared distance over a layer as
    :func:`grid_square` gives it.
    """

    options: tuple[str, ...]
    resolve: Callable[..., Reference]
    distance: Callable[[Reference, np.ndarray, Callable | None], np.ndarray]
    written: Callable[[Reference], str]
    closed_form: Callable | None = None
    square: Callable[[Reference, float], tuple[float, ...]] | None = None


#: The kinds of reference feature, by name. Defaults: plane = normal +Z through the model's
#: extreme point against the normal (the X-Y plane through the lowest point); point = the
#: bounding-box centre; axis = vertical (or ``direction``) through the bounding-box centre;
#: surface = the model's own surface, or a second mesh.
REFERENCES: dict[str, ReferenceKind] = {
    "plane": ReferenceKind(("at", "normal"), _resolve_plane, _columns(_plane_at),
                           lambda ref: f"plane through {_text(ref.point)} with normal {_text(ref.direction)}",
                           _plane_at, _plane_square),
    "point": ReferenceKind(("at",), _resolve_point, _columns(_point_at),
                           lambda ref: f"point {_text(ref.point)}", _point_at, _point_square),
    "axis": ReferenceKind(("at", "direction"), _resolve_axis, _columns(_axis_at),
                          lambda ref: f"axis through {_text(ref.point)} along {_text(ref.direction)}", _axis_at,
                          _axis_square),
    "surface": ReferenceKind(("surface",), _resolve_surface, _surface_distance,
                             lambda ref: f"surface of {len(ref.surface.faces)} triangles"),
}
REFERENCE_KINDS = tuple(REFERENCES)


def reference_kinds_taking(option: str) -> tuple[str, ...]:
    """The reference kinds that take a geometry option (``at``, ``normal``, ``direction``, ``surface``)."""
    return tuple(name for name, row in REFERENCES.items() if option in row.options)


def make_reference(kind: str, vertices: np.ndarray, faces: np.ndarray | None = None, *,
                   at=None, normal=None, direction=None,
                   surface: tuple[np.ndarray, np.ndarray] | None = None) -> Reference:
    """Resolve a reference feature against the model (vertices (n, 3) mm, faces (m, 3)); see :data:`REFERENCES`.

    ``surface`` = (vertices, faces) of a second mesh for a surface reference.
    """
    name = str(kind).strip().lower()
    if name not in REFERENCES:
        raise InputError(f"kind: unknown reference {name!r} (choose from {', '.join(REFERENCE_KINDS)})")
    for option, value in (("at", at), ("normal", normal), ("direction", direction), ("surface", surface)):
        if value is not None and option not in REFERENCES[name].options:
            raise InputError(f"{option}: only applies to a {' or '.join(reference_kinds_taking(option))} "
                             f"reference, not {name!r}")
    vertices = np.asarray(vertices, dtype=np.float64)
    return REFERENCES[name].resolve(vertices, faces, at, normal, direction, surface)


def reference_distance(reference: Reference, points: np.ndarray,
                       progress: Callable[[int, int], None] | None = None) -> np.ndarray:
    """Minimum distance (n,) float64 mm from each point (n, 3) mm to the reference feature.

    ``progress(done, total)`` is called as points are done (only a surface takes long).
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return REFERENCES[reference.kind].distance(reference, points, progress)


def grid_distance(reference: Reference, x: np.ndarray, y: np.ndarray, z: float) -> np.ndarray:
    """Distance float64 mm from the points of a layer's pixel grid (x (w,), y (h,) mm, height z) to a plane,
    point or axis, in closed form over the whole grid at once (the same formula as
    :func:`reference_distance`): an array that broadcasts to (h, w), of shape (1, 1), (h, 1) or (1, w) where
    the distance does not change along a grid axis. Raises ValueError for a surface (searched point by point)."""
    at = REFERENCES[reference.kind].closed_form
    if at is None:
        raise ValueError(f"a {reference.kind} reference has no closed-form distance")
    x = np.asarray(x, dtype=np.float64)[None, :]
    y = np.asarray(y, dtype=np.float64)[:, None]
    distance = np.asarray(at(reference, x, y, float(z)), dtype=np.float64)
    return distance.reshape(np.broadcast_shapes(distance.shape, (1, 1)))


def grid_square(reference: Reference, z: float) -> tuple[float, ...]:
    """The squared distance from a plane, point or axis over the layer at height z (mm) as (A, B, C, D, E, F):
    A u^2 + B u v + C v^2 + D u + E v + F, u and v a point's offsets (mm) from the reference's point along x and
    y. Raises ValueError for a surface."""
    square = REFERENCES[reference.kind].square
    if square is None:
        raise ValueError(f"a {reference.kind} reference has no closed-form distance")
    return tuple(float(c) for c in square(reference, float(z)))


def normalise(distance: np.ndarray, r_range: tuple[float, float] | None = None) -> np.ndarray:
    """r (n,) in [0, 1]: distance / its maximum, or (distance - R0) / (R1 - R0) clipped.

    ``r_range`` = (R0, R1) in mm. A range of zero width (every distance 0 by default,
    or R1 <= R0) raises InputError naming ``r_range``.
    """
    distance = np.asarray(distance, dtype=np.float64)
    if r_range is None:
        top = float(distance.max(initial=0.0))
        if not top > 0.0:
            raise InputError("r_range: every point is at distance 0 from the reference: the range is of zero "
                             "width (choose another reference or give a range in mm)")
        return np.clip(distance / top, 0.0, 1.0)
    low, high = (finite("r_range", v) for v in r_range)
    if not high > low:
        raise InputError(f"r_range: {low:g} {high:g} mm is of zero or negative width (need R0 < R1)")
    r = np.asarray((distance - low) / (high - low))
    return np.clip(r, 0.0, 1.0, out=r) if r.ndim else np.clip(r, 0.0, 1.0)


def material_fraction(points: np.ndarray, reference: Reference, func: DistributionFunction,
                      r_range: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(r, f) for points (n, 3) mm: normalised distance to the reference and f(r) (not clipped)."""
    r = normalise(reference_distance(reference, points), r_range)
    return r, evaluate(func, r)
