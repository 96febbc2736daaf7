"""Material distribution functions (paper section II.B, eq. 2-5) and the distances they take.

A material distribution is a reference feature (a plane, point, axis or surface), the
minimum distance of each point to it, that distance normalised to r in [0, 1], and a
function f(r) whose value is the fraction of the second material M2 (eq. 1 in
:mod:`heoslice.materials` turns f into a blend). Everything here works on (n, 3)
arrays of points in mm, vectorised; nothing here knows about files or the CLI.

The functions, with the defaults :func:`make_function` fills so that f spans 0..1
over r in [0, 1]:

=========== ========================= =======================================
kind        f(r)                      defaults
=========== ========================= =======================================
constant    lam                 (2)   lam = 1 (the whole model is M2)
linear      alpha r + lam       (3)   alpha = 1, lam = 0
quadratic   alpha r^2 + beta r + lam  alpha = 1, beta = 0, lam = 0      (4)
sine        alpha sin(beta r) + lam   alpha = 0.5, lam = 0.5,
                                (5)   beta = 2 pi periods, periods = 1
expression  a formula in r            e.g. ``"0.5 - 0.5*cos(3*pi*r)"``
=========== ========================= =======================================

Expressions are parsed with :mod:`ast` and evaluated by a small interpreter that knows
only numbers, ``r``, ``pi``, ``e``, ``+ - * / **``, unary minus and a whitelist of
numpy functions; nothing is passed to ``eval``.
"""

from __future__ import annotations

import ast
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from heoslice.errors import InputError

FUNCTION_KINDS = ("constant", "linear", "quadratic", "sine", "expression")
REFERENCE_KINDS = ("plane", "point", "axis", "surface")

#: Functions an expression may call: name -> (numpy function, number of arguments).
EXPRESSION_FUNCTIONS = {
    "sin": (np.sin, 1), "cos": (np.cos, 1), "tan": (np.tan, 1),
    "arcsin": (np.arcsin, 1), "arccos": (np.arccos, 1), "arctan": (np.arctan, 1),
    "sinh": (np.sinh, 1), "cosh": (np.cosh, 1), "tanh": (np.tanh, 1),
    "exp": (np.exp, 1), "log": (np.log, 1), "log2": (np.log2, 1), "log10": (np.log10, 1),
    "sqrt": (np.sqrt, 1), "abs": (np.abs, 1), "floor": (np.floor, 1), "ceil": (np.ceil, 1),
    "round": (np.round, 1), "sign": (np.sign, 1),
    "min": (np.minimum, 2), "max": (np.maximum, 2), "clip": (np.clip, 3),
}
EXPRESSION_CONSTANTS = {"pi": math.pi, "e": math.e}
_EXPRESSION_MAX_CHARS = 1000
_EXPRESSION_MAX_NODES = 500
_BINARY = {ast.Add: np.add, ast.Sub: np.subtract, ast.Mult: np.multiply,
           ast.Div: np.divide, ast.Pow: np.power}


@dataclass(frozen=True)
class DistributionFunction:
    """f(r) of eq. 2-5 (or a user ``expression`` in r); f is the fraction of M2 at r."""

    kind: str
    alpha: float = 1.0
    beta: float = 0.0
    lam: float = 0.0
    expression: str | None = None

    def __call__(self, r: np.ndarray) -> np.ndarray:
        return evaluate(self, r)

    def describe(self) -> str:
        """One line for logs and PLY comments, e.g. ``linear: f = 1*r + 0``."""
        a, b, lam = (f"{v:.6g}" for v in (self.alpha, self.beta, self.lam))
        return {
            "constant": f"constant: f = {lam}",
            "linear": f"linear: f = {a}*r + {lam}",
            "quadratic": f"quadratic: f = {a}*r^2 + {b}*r + {lam}",
            "sine": f"sine: f = {a}*sin({b}*r) + {lam}",
            "expression": f"expression: f = {self.expression}",
        }[self.kind]


def _finite(name: str, value) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(number):
        raise InputError(f"{name} must be finite, got {value!r}")
    return number


def make_function(kind: str, alpha: float | None = None, beta: float | None = None,
                  lam: float | None = None, periods: float | None = None,
                  expression: str | None = None) -> DistributionFunction:
    """A :class:`DistributionFunction` with the documented defaults filled in.

    Raises InputError for an unknown kind, non-finite coefficients, a coefficient the
    kind does not use (beta for linear...), ``periods`` together with ``beta``, or an
    expression that does not parse or uses anything outside the whitelist.
    """
    kind = str(kind).strip().lower()
    if kind not in FUNCTION_KINDS:
        raise InputError(f"unknown distribution function {kind!r} (choose from {', '.join(FUNCTION_KINDS)})")
    if expression is not None and kind != "expression":
        raise InputError(f"an expression is only used with the 'expression' function, not {kind!r}")
    if periods is not None and kind != "sine":
        raise InputError(f"periods only applies to the 'sine' function, not {kind!r}")
    values = {name: (None if v is None else _finite(name, v))
              for name, v in (("alpha", alpha), ("beta", beta), ("lambda", lam), ("periods", periods))}
    unused = {"constant": ("alpha", "beta"), "linear": ("beta",),
              "expression": ("alpha", "beta", "lambda")}.get(kind, ())
    stray = [name for name in unused if values[name] is not None]
    if stray:
        raise InputError(f"{' and '.join(stray)} {'is' if len(stray) == 1 else 'are'} not used by the {kind} "
                         "function (see its formula)")
    if kind == "expression":
        if expression is None or not str(expression).strip():
            raise InputError("the 'expression' function needs an expression in r, e.g. '0.5 - 0.5*cos(2*pi*r)'")
        compile_expression(expression)
        return DistributionFunction("expression", expression=str(expression).strip())
    if kind == "constant":
        return DistributionFunction("constant", alpha=0.0, beta=0.0,
                                    lam=1.0 if values["lambda"] is None else values["lambda"])
    if kind == "sine":
        if values["periods"] is not None and values["beta"] is not None:
            raise InputError("give either beta or periods for the sine function, not both")
        periods_value = 1.0 if values["periods"] is None else values["periods"]
        return DistributionFunction(
            "sine",
            alpha=0.5 if values["alpha"] is None else values["alpha"],
            beta=2.0 * math.pi * periods_value if values["beta"] is None else values["beta"],
            lam=0.5 if values["lambda"] is None else values["lambda"],
        )
    return DistributionFunction(
        kind,
        alpha=1.0 if values["alpha"] is None else values["alpha"],
        beta=0.0 if values["beta"] is None else values["beta"],
        lam=0.0 if values["lambda"] is None else values["lambda"],
    )


def evaluate(func: DistributionFunction, r: np.ndarray) -> np.ndarray:
    """f(r) for r (n,) float in [0, 1]: eq. 2 (constant), 3 (linear), 4 (quadratic), 5 (sine).

    Returns (n,) float64, not clipped (eq. 1's blend clips). An expression that is
    undefined (NaN) at some r raises InputError naming that r.
    """
    r = np.asarray(r, dtype=np.float64)
    if func.kind == "constant":
        return np.full(r.shape, func.lam)
    if func.kind == "linear":
        return func.alpha * r + func.lam
    if func.kind == "quadratic":
        return (func.alpha * r + func.beta) * r + func.lam
    if func.kind == "sine":
        return func.alpha * np.sin(func.beta * r) + func.lam
    if func.kind == "expression":
        return _evaluate_expression(func.expression or "", r)
    raise InputError(f"unknown distribution function {func.kind!r}")


# --- safe expressions -------------------------------------------------------------------

def compile_expression(text: str) -> ast.Expression:
    """Parse and check an expression in r; raise InputError naming what is not allowed."""
    text = str(text)
    if len(text) > _EXPRESSION_MAX_CHARS:
        raise InputError(f"expression is longer than {_EXPRESSION_MAX_CHARS} characters")
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except (SyntaxError, ValueError, RecursionError, MemoryError) as err:
        detail = getattr(err, "msg", None) or type(err).__name__
        raise InputError(f"expression {text!r} does not parse ({detail})") from None
    nodes = list(ast.walk(tree))
    if len(nodes) > _EXPRESSION_MAX_NODES:
        raise InputError(f"expression {text!r} is too complex (more than {_EXPRESSION_MAX_NODES} parts)")
    for node in nodes:
        _check_node(node, text)
    called = {id(node.func) for node in nodes if isinstance(node, ast.Call)}
    for node in nodes:
        if isinstance(node, ast.Name) and node.id in EXPRESSION_FUNCTIONS and id(node) not in called:
            raise InputError(f"expression {text!r}: {node.id!r} is a function, call it with ()")
    return tree


def _check_node(node: ast.AST, text: str) -> None:
    """Refuse every AST node outside the whitelist."""
    allowed = (ast.Expression, ast.BinOp, ast.UnaryOp, ast.Constant, ast.Name, ast.Call, ast.Load,
               ast.UAdd, ast.USub, *_BINARY)
    if not isinstance(node, allowed):
        raise InputError(f"expression {text!r}: {type(node).__name__.lower()} is not allowed "
                         "(use numbers, r, pi, e, + - * / ** and functions like sin, exp, clip)")
    if isinstance(node, ast.Constant) and (isinstance(node.value, bool)
                                           or not isinstance(node.value, (int, float))):
        raise InputError(f"expression {text!r}: only numbers are allowed as constants, not {node.value!r}")
    if isinstance(node, ast.Name) and node.id != "r" and node.id not in EXPRESSION_CONSTANTS \
            and node.id not in EXPRESSION_FUNCTIONS:
        raise InputError(f"expression {text!r}: unknown name {node.id!r} (the variable is r; constants pi, e)")
    if isinstance(node, ast.Call):
        if not isinstance(node.func, ast.Name) or node.func.id not in EXPRESSION_FUNCTIONS:
            name = node.func.id if isinstance(node.func, ast.Name) else ast.unparse(node.func)
            raise InputError(f"expression {text!r}: unknown function {name!r} "
                             f"(allowed: {', '.join(sorted(EXPRESSION_FUNCTIONS))})")
        arity = EXPRESSION_FUNCTIONS[node.func.id][1]
        if node.keywords or len(node.args) != arity:
            raise InputError(f"expression {text!r}: {node.func.id}() takes {arity} argument(s)")


def _evaluate_expression(text: str, r: np.ndarray) -> np.ndarray:
    """Vectorised value of a checked expression at every r; (n,) float64."""
    tree = compile_expression(text)

    def value(node: ast.AST):
        if isinstance(node, ast.Expression):
            return value(node.body)
        if isinstance(node, ast.Constant):
            return np.float64(node.value)
        if isinstance(node, ast.Name):
            if node.id == "r":
                return r
            return np.float64(EXPRESSION_CONSTANTS[node.id])
        if isinstance(node, ast.UnaryOp):
            operand = value(node.operand)
            return -operand if isinstance(node.op, ast.USub) else +operand
        if isinstance(node, ast.BinOp):
            return _BINARY[type(node.op)](value(node.left), value(node.right))
        function = EXPRESSION_FUNCTIONS[node.func.id][0]
        return function(*(value(arg) for arg in node.args))

    with np.errstate(all="ignore"):
        try:
            result = np.broadcast_to(np.asarray(value(tree), dtype=np.float64), r.shape).copy()
        except RecursionError:
            raise InputError(f"expression {text!r} is nested too deeply") from None
    bad = np.isnan(result)
    if bad.any():
        raise InputError(f"expression {text!r} is undefined (NaN) at r = {float(r[bad].flat[0]):.6g}")
    return result


# --- reference features and distances ----------------------------------------------------

@dataclass(frozen=True, eq=False)
class SurfaceIndex:
    """A triangle surface prepared for closest-point queries (see :func:`surface_distance`).

    vertices (v, 3) float64 mm, faces (m, 3) int64; vertex_faces (v, k) and
    vertex_neighbours (v, j) and face_neighbours (m, i) int64 adjacency padded with -1;
    seeds (s,) int64 face of each start point, seed_tree the scipy cKDTree of the start
    points (s, 3) on those faces; seed_spacing: every surface point is within this
    distance (mm) of a start point.
    """

    vertices: np.ndarray
    faces: np.ndarray
    vertex_faces: np.ndarray
    vertex_neighbours: np.ndarray
    face_neighbours: np.ndarray
    seeds: np.ndarray
    seed_tree: object = field(repr=False)
    seed_spacing: float = 0.0


@dataclass(frozen=True, eq=False)
class Reference:
    """A reference feature with every default resolved.

    kind: 'plane' | 'point' | 'axis' | 'surface'. point: (3,) mm, a point of the plane or
    axis, or the point itself. direction: (3,) unit normal of the plane or direction of the
    axis (None otherwise). surface: the indexed reference surface for kind 'surface'.
    """

    kind: str
    point: tuple[float, float, float] | None = None
    direction: tuple[float, float, float] | None = None
    surface: SurfaceIndex | None = None

    def describe(self) -> str:
        """One line for logs and PLY comments."""
        fmt = lambda v: "(" + ", ".join(f"{x + 0.0:.6g}" for x in np.round(v, 9)) + ")"  # noqa: E731
        if self.kind == "plane":
            return f"plane through {fmt(self.point)} with normal {fmt(self.direction)}"
        if self.kind == "point":
            return f"point {fmt(self.point)}"
        if self.kind == "axis":
            return f"axis through {fmt(self.point)} along {fmt(self.direction)}"
        return f"surface of {len(self.surface.faces)} triangles"


def _vector(name: str, value, unit: bool = False) -> np.ndarray:
    try:
        vector = np.asarray(value, dtype=np.float64).reshape(3)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be three numbers x,y,z, got {value!r}") from None
    if not np.isfinite(vector).all():
        raise InputError(f"{name} must be finite, got {value!r}")
    if unit:
        length = float(np.linalg.norm(vector))
        if length == 0.0:
            raise InputError(f"{name} must not be the zero vector")
        vector = vector / length
    return vector


def make_reference(kind: str, vertices: np.ndarray, faces: np.ndarray | None = None, *,
                   at=None, normal=None, direction=None,
                   surface: tuple[np.ndarray, np.ndarray] | None = None) -> Reference:
    """Resolve a reference feature against the model (vertices (n, 3) mm, faces (m, 3)).

    Defaults: plane = normal +Z through the model's extreme point against the normal
    (the X-Y plane through the lowest point); point = bounding-box centre; axis =
    vertical (or ``direction``) through the bounding-box centre; surface = the model's
    own surface, or ``surface`` = (vertices, faces) of a second mesh.
    """
    kind = str(kind).strip().lower()
    if kind not in REFERENCE_KINDS:
        raise InputError(f"unknown reference {kind!r} (choose from {', '.join(REFERENCE_KINDS)})")
    vertices = np.asarray(vertices, dtype=np.float64)
    if normal is not None and kind != "plane":
        raise InputError(f"a normal only applies to a plane reference, not {kind!r}")
    if direction is not None and kind != "axis":
        raise InputError(f"a direction only applies to an axis reference, not {kind!r}")
    if surface is not None and kind != "surface":
        raise InputError(f"a reference surface only applies to a surface reference, not {kind!r}")
    if at is not None and kind == "surface":
        raise InputError("a point does not apply to a surface reference")
    centre = (vertices.min(axis=0) + vertices.max(axis=0)) / 2.0
    if kind == "plane":
        n = _vector("normal", (0.0, 0.0, 1.0) if normal is None else normal, unit=True)
        p = vertices[np.argmin(vertices @ n)] if at is None else _vector("point", at)
        return Reference("plane", tuple(map(float, p)), tuple(map(float, n)))
    if kind == "point":
        p = centre if at is None else _vector("point", at)
        return Reference("point", tuple(map(float, p)))
    if kind == "axis":
        u = _vector("direction", (0.0, 0.0, 1.0) if direction is None else direction, unit=True)
        p = centre if at is None else _vector("point", at)
        return Reference("axis", tuple(map(float, p)), tuple(map(float, u)))
    if surface is None:
        if faces is None:
            raise InputError("a surface reference on the model itself needs the model's faces")
        surface = (vertices, faces)
    return Reference("surface", surface=build_surface_index(*surface))


def reference_distance(reference: Reference, points: np.ndarray,
                       progress: Callable[[int, int], None] | None = None) -> np.ndarray:
    """Minimum distance (n,) float64 mm from each point (n, 3) mm to the reference feature.

    ``progress(done, total)`` is called as points are done (only a surface takes long).
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if reference.kind == "surface":
        return surface_distance(points, reference.surface, progress=progress)
    offset = points - np.asarray(reference.point)
    if reference.kind == "point":
        return np.sqrt(np.einsum("ij,ij->i", offset, offset))
    along = offset @ np.asarray(reference.direction)
    if reference.kind == "plane":
        return np.abs(along)
    across = offset - along[:, None] * np.asarray(reference.direction)
    return np.sqrt(np.einsum("ij,ij->i", across, across))


def normalise(distance: np.ndarray, r_range: tuple[float, float] | None = None) -> np.ndarray:
    """r (n,) in [0, 1]: distance / its maximum, or (distance - R0) / (R1 - R0) clipped.

    ``r_range`` = (R0, R1) in mm. A range of zero width (every distance 0 by default,
    or R1 <= R0) raises InputError.
    """
    distance = np.asarray(distance, dtype=np.float64)
    if r_range is None:
        top = float(distance.max(initial=0.0))
        if not top > 0.0:
            raise InputError("every point is at distance 0 from the reference: the range is of zero width "
                             "(choose another reference or give a range in mm)")
        return np.clip(distance / top, 0.0, 1.0)
    low, high = (_finite("range", v) for v in r_range)
    if not high > low:
        raise InputError(f"range {low:g} {high:g} mm is of zero or negative width (need R0 < R1)")
    return np.clip((distance - low) / (high - low), 0.0, 1.0)


def material_fraction(points: np.ndarray, reference: Reference, func: DistributionFunction,
                      r_range: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(r, f) for points (n, 3) mm: normalised distance to the reference and f(r) (not clipped)."""
    r = normalise(reference_distance(reference, points), r_range)
    return r, evaluate(func, r)


# --- distance to a triangle surface -----------------------------------------------------

def _padded(groups: np.ndarray, members: np.ndarray, count: int) -> np.ndarray:
    """Rows of ``members`` grouped by ``groups`` (0..count-1), as a (count, width) array padded with -1."""
    order = np.lexsort((members, groups))
    groups, members = groups[order], members[order]
    keep = np.ones(len(groups), dtype=bool)
    keep[1:] = (groups[1:] != groups[:-1]) | (members[1:] != members[:-1])
    groups, members = groups[keep], members[keep]
    sizes = np.bincount(groups, minlength=count)
    width = int(sizes.max(initial=1))
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    table = np.full((count, max(width, 1)), -1, dtype=np.int64)
    table[groups, np.arange(len(groups)) - starts[groups]] = members
    return table


def build_surface_index(vertices: np.ndarray, faces: np.ndarray, seed_count: int = 1024) -> SurfaceIndex:
    """Adjacency tables and a tree of about ``seed_count`` start points for :func:`surface_distance`.

    vertices (v, 3) mm, faces (m, 3). Fewer start points make far queries faster
    (scipy's tree slows down when many points are nearly equidistant) and the downhill
    walks longer; 1024 measured best on benchmarks/bench_color.py.
    """
    from scipy.spatial import cKDTree

    vertices = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
    faces = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(faces) == 0:
        raise InputError("the reference surface has no triangles")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise InputError("the reference surface has face indices outside its vertex list")
    if not np.isfinite(vertices).all():
        raise InputError("the reference surface has NaN or infinite coordinates")
    nv, nf = len(vertices), len(faces)
    corner_face = np.repeat(np.arange(nf), 3)
    vertex_faces = _padded(faces.ravel(), corner_face, nv)
    edges = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    vertex_neighbours = _padded(np.concatenate([edges[:, 0], edges[:, 1]]),
                                np.concatenate([edges[:, 1], edges[:, 0]]), nv)
    around = vertex_faces[faces].reshape(nf, -1)
    rows = np.repeat(np.arange(nf), around.shape[1])
    flat = around.ravel()
    valid = (flat >= 0) & (flat != rows)
    face_neighbours = _padded(rows[valid], flat[valid], nf)
    points, owner, spacing = _seed_points(vertices, faces, seed_count)
    return SurfaceIndex(vertices, faces, vertex_faces, vertex_neighbours, face_neighbours,
                        owner, cKDTree(points), spacing)


def _seed_points(vertices: np.ndarray, faces: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray, float]:
    """About ``count`` start points on the surface: (points (s, 3), face of each (s,), covering radius mm).

    Triangles longer than a grid cell are split into sub-triangles no longer than the cell,
    whose centroids are all kept; the other triangles keep one centroid per grid cell. Every
    surface point is then within the returned radius of a start point.
    """
    corners = vertices[faces]
    longest = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
    area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    cell = max(math.sqrt(2.0 * max(float(area.sum()), 1e-300) / max(count, 1)), 1e-9)
    splits = np.maximum(np.ceil(longest / cell), 1).astype(np.int64)
    for _ in range(60):  # keep the number of sub-triangles bounded on meshes with huge triangles
        if int((splits ** 2).sum()) <= 4 * count + len(faces):
            break
        cell *= 1.25
        splits = np.maximum(np.ceil(longest / cell), 1).astype(np.int64)
    # sub-triangle centroids: s*(s+1)/2 upward and s*(s-1)/2 downward ones per triangle
    up, down = splits * (splits + 1) // 2, splits * (splits - 1) // 2
    face = np.concatenate([np.repeat(np.arange(len(faces)), up), np.repeat(np.arange(len(faces)), down)])
    rank = np.concatenate([np.arange(up.sum()) - np.repeat(np.cumsum(up) - up, up),
                           np.arange(down.sum()) - np.repeat(np.cumsum(down) - down, down)])
    is_up = np.concatenate([np.ones(up.sum(), bool), np.zeros(down.sum(), bool)])
    size = splits[face] - (~is_up)  # rows of the triangular index grid
    row = (np.floor((np.sqrt(8.0 * rank + 1) - 1) / 2)).astype(np.int64)  # rank -> (row, column)
    row = np.where((row + 1) * (row + 2) // 2 <= rank, row + 1, row)
    row = np.where(row * (row + 1) // 2 > rank, row - 1, row)
    column = rank - row * (row + 1) // 2
    i, j = size - 1 - row, column  # i + j <= size - 1
    offset = np.where(is_up, 1.0 / 3.0, 2.0 / 3.0)
    u = (i + offset) / splits[face]
    v = (j + offset) / splits[face]
    a = corners[face, 0]
    points = a + u[:, None] * (corners[face, 1] - a) + v[:, None] * (corners[face, 2] - a)
    small = splits[face] == 1
    if len(points) <= count:
        return points, face, float((longest / splits).max())  # a point is within an edge of its centroid
    keys = np.floor((points[small] - points.min(axis=0)) / cell).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    keep = np.concatenate([np.nonzero(small)[0][first], np.nonzero(~small)[0]])
    # a point of a small triangle is within its longest edge of the centroid, which is within
    # a cell diagonal of the kept centroid of its cell; split triangles are covered by their own
    radius = float(longest[splits == 1].max(initial=0.0)) + math.sqrt(3.0) * cell
    return points[keep], face[keep], max(radius, cell)


def _closest_parameters(ap: np.ndarray, ab: np.ndarray, ac: np.ndarray):
    """Barycentric (s, t) (n,) of the closest point a + s ab + t ac, and its region (n,) int8.

    Regions: 0 vertex a, 1 vertex b, 2 vertex c, 3 edge ab, 4 edge ac, 5 edge bc, 6 inside.
    Ericson's region test (Real-Time Collision Detection, 5.1.5), vectorised.
    """
    dot = lambda u, v: np.einsum("ij,ij->i", u, v)  # noqa: E731
    d1, d2 = dot(ab, ap), dot(ac, ap)
    abab, abac, acac = dot(ab, ab), dot(ab, ac), dot(ac, ac)
    d3, d4 = d1 - abab, d2 - abac          # ab.(p-b), ac.(p-b)
    d5, d6 = d1 - abac, d2 - acac          # ab.(p-c), ac.(p-c)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        denom = va + vb + vc
        v, w = vb / denom, vc / denom
    region = np.select(
        [(d1 <= 0) & (d2 <= 0), (d3 >= 0) & (d4 <= d3), (d6 >= 0) & (d5 <= d6),
         (vc <= 0) & (d1 >= 0) & (d3 <= 0), (vb <= 0) & (d2 >= 0) & (d6 <= 0),
         (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)],
        [0, 1, 2, 3, 4, 5], default=6).astype(np.int8)
    zero = np.zeros_like(d1)
    s = np.choose(region, [zero, zero + 1.0, zero, t_ab, zero, 1.0 - t_bc, v])
    t = np.choose(region, [zero, zero, zero + 1.0, zero, t_ac, t_bc, w])
    return s, t, region


def closest_points_on_triangles(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Closest point (n, 3) on each triangle (n, 3, 3) to each point (n, 3), all mm.

    A degenerate (zero-area) triangle is handled as the closest of its three edges.
    """
    p = np.asarray(points, dtype=np.float64)
    triangles = np.asarray(triangles, dtype=np.float64)
    a = triangles[:, 0]
    ab, ac = triangles[:, 1] - a, triangles[:, 2] - a
    s, t, _ = _closest_parameters(p - a, ab, ac)
    result = a + s[:, None] * ab + t[:, None] * ac
    broken = ~np.isfinite(result).all(axis=1)
    if broken.any():
        result[broken] = _closest_on_edges(p[broken], triangles[broken])
    return result


def _closest_on_edges(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Closest point on the three edges of (degenerate) triangles; (n, 3)."""
    best = np.empty_like(points)
    best_d = np.full(len(points), np.inf)
    for i, j in ((0, 1), (1, 2), (2, 0)):
        start, seg = triangles[:, i], triangles[:, j] - triangles[:, i]
        length2 = np.einsum("ij,ij->i", seg, seg)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(length2 > 0, np.einsum("ij,ij->i", points - start, seg) / length2, 0.0)
        q = start + np.clip(t, 0.0, 1.0)[:, None] * seg
        d = np.einsum("ij,ij->i", points - q, points - q)
        closer = d < best_d
        best[closer], best_d[closer] = q[closer], d[closer]
    return best


def point_triangle_distance(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Distance (n,) mm from each point (n, 3) to the matching triangle (n, 3, 3)."""
    gap = np.asarray(points, dtype=np.float64) - closest_points_on_triangles(points, triangles)
    return np.sqrt(np.einsum("ij,ij->i", gap, gap))


def _face_distance(points: np.ndarray, index: SurfaceIndex, faces: np.ndarray):
    """Distances (n, k) from points (n, 3) to faces (n, k) int (-1 = none: inf), and regions (n, k) int8.

    Regions as :func:`_closest_parameters`; -1 where a triangle is degenerate.
    """
    n, k = faces.shape
    tri = index.vertices[index.faces[np.maximum(faces, 0)]].reshape(n * k, 3, 3)
    p = np.repeat(points, k, axis=0)
    a = tri[:, 0]
    ab, ac, ap = tri[:, 1] - a, tri[:, 2] - a, p - a
    s, t, region = _closest_parameters(ap, ab, ac)
    gap = ap - s[:, None] * ab - t[:, None] * ac
    d = np.sqrt(np.einsum("ij,ij->i", gap, gap))
    broken = ~np.isfinite(d)
    if broken.any():
        d[broken] = point_triangle_distance(p[broken], tri[broken])
        region[broken] = -1
    d = d.reshape(n, k)
    d[faces < 0] = np.inf
    return d, region.reshape(n, k)


#: For each closest-point region: the triangle corners (0, 1, 2) it touches.
_REGION_CORNERS = np.array([[0, 0], [1, 1], [2, 2], [0, 1], [0, 2], [1, 2]])


def surface_distance(points: np.ndarray, index: SurfaceIndex, seeds_per_point: int = 1,
                     chunk: int = 65536, progress: Callable[[int, int], None] | None = None) -> np.ndarray:
    """Unsigned distance (n,) mm from points (n, 3) mm to a triangle surface.

    Each point starts at its nearest start points on the surface (scipy cKDTree over
    about ``seed_count`` points, see :func:`build_surface_index`), walks downhill over the
    vertex graph to a vertex nearer than all its neighbours, takes the nearest of the
    triangles around it and the start triangle (exact point-triangle distances), then
    walks downhill over triangles until no triangle sharing a vertex with the current
    one is nearer. The result is the exact distance to a locally closest triangle, which
    is the global one unless another part of the surface is almost as near: it is never
    below the true distance, and never above the distance to the nearest start point
    (so at most ``index.seed_spacing`` above it). ``progress(done, total)`` follows the chunks.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.empty(len(points))
    k = max(1, min(int(seeds_per_point), len(index.seeds)))
    for start in range(0, len(points), chunk):
        block = points[start:start + chunk]
        _, nearest = index.seed_tree.query(block, k=k)
        nearest = np.asarray(nearest).reshape(len(block), k)
        best = np.full(len(block), np.inf)
        for column in range(k):
            best = np.minimum(best, _descend(block, index, index.seeds[nearest[:, column]]))
        out[start:start + chunk] = best
        if progress is not None:
            progress(min(start + chunk, len(points)), len(points))
    return out


def _descend(points: np.ndarray, index: SurfaceIndex, start_face: np.ndarray) -> np.ndarray:
    """Downhill walk from start faces (n,) to a locally nearest triangle; (n,) distances."""
    vertices = index.vertices
    rows = np.arange(len(points))
    start_d, _ = _face_distance(points, index, start_face[:, None])
    start_d = start_d[:, 0]
    corner = index.faces[start_face]
    gap = points[:, None, :] - vertices[corner]
    corner_d = np.einsum("ijk,ijk->ij", gap, gap)
    current = corner[rows, np.argmin(corner_d, axis=1)]
    current_d = corner_d.min(axis=1)

    def vertex_step(active):
        around = index.vertex_neighbours[current[active]]
        diff = points[active, None, :] - vertices[np.maximum(around, 0)]
        return around, np.where(around >= 0, np.einsum("ijk,ijk->ij", diff, diff), np.inf)

    _walk_downhill(current, current_d, rows, vertex_step)
    ring = index.vertex_faces[current]
    d, region = _face_distance(points, index, ring)
    pick = np.argmin(d, axis=1)
    face, face_d, face_region = ring[rows, pick], d[rows, pick], region[rows, pick]
    # The whole ring of `current` was measured: the nearest point is a local minimum when it is
    # inside the face, or on a corner or edge touching `current` (its neighbourhood is in the ring).
    corners = index.faces[face][rows[:, None], _REGION_CORNERS[np.maximum(face_region, 0) % 6]]
    settled = (face_region == 6) | ((face_region >= 0) & (corners == current[:, None]).any(axis=1))
    # The vertex walk can cross to another sheet (the far wall of a thin part); the start face may be nearer.
    from_start = start_d < face_d
    face[from_start], face_d[from_start] = start_face[from_start], start_d[from_start]
    settled &= ~from_start

    def face_step(active):
        around = index.face_neighbours[face[active]]
        return around, _face_distance(points[active], index, around)[0]

    _walk_downhill(face, face_d, np.nonzero(~settled)[0], face_step)
    return face_d


def _walk_downhill(position: np.ndarray, distance: np.ndarray, active: np.ndarray, step) -> None:
    """Move each active walker to its nearest neighbour while that is nearer, in place, all walkers at once.

    ``step(active)`` returns the candidates ((k, c) int, one row per active walker) and
    their distances ((k, c) float, inf for none); a walker stops when no candidate is
    nearer than where it stands.
    """
    while len(active):
        around, d = step(active)
        pick = np.argmin(d, axis=1)
        d_pick = d[np.arange(len(active)), pick]
        moved = d_pick < distance[active]
        active = active[moved]
        position[active] = around[moved, pick[moved]]
        distance[active] = d_pick[moved]
