"""Test helpers: slice a trimesh in memory, random rings, and independent references to compare against."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
import zipfile

import manifold3d
import numpy as np
import shapely
import trimesh

from heoslice.grading.edges import ring_edges
from heoslice.grading.halftone import thresholds
from heoslice.grading.labels import family_of
from heoslice.grading.search import LazyTree, RingSet
from heoslice.grading.search_kernels import edge_tree
from heoslice.layers import plane_heights, slice_mesh
from heoslice.layers.contours import Contours, build_contours
from heoslice.layers.rasterising import Grid


def contours_of(mesh, layer_height: float) -> tuple[np.ndarray, Contours]:
    """Planes and contours of a trimesh-like (vertices, faces) at layer centres."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    z = plane_heights(vertices[:, 2].min(), vertices[:, 2].max(), layer_height)
    return z, build_contours(slice_mesh(vertices, np.asarray(mesh.faces), z))


def manifold_areas(vertices: np.ndarray, faces: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Per-plane cross-section areas from manifold3d's slice, in double precision (the reference)."""
    solid = manifold3d.Manifold(manifold3d.Mesh64(vert_properties=np.ascontiguousarray(vertices, np.float64),
                                                  tri_verts=np.ascontiguousarray(faces, np.uint64)))
    assert solid.status() == manifold3d.Error.NoError, solid.status()
    return np.array([solid.slice(float(height)).area() for height in z])


def layer_loops(contours: Contours, layer: int) -> tuple[np.ndarray, np.ndarray]:
    """(points, offsets) of one layer's loops, offsets starting at 0."""
    first, last = contours.layer_offsets[layer], contours.layer_offsets[layer + 1]
    start = contours.offsets[first]
    return contours.points[start:contours.offsets[last]], contours.offsets[first:last + 1] - start


def winding_reference(points: np.ndarray, offsets: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Winding number of closed loops at points (x, y) by shapely point-in-polygon, one loop at a time."""
    winding = np.zeros(np.shape(x), dtype=np.int64)
    for start, stop in zip(offsets[:-1], offsets[1:]):
        ring = points[start:stop]
        if len(ring) < 3:
            continue
        sign = 1 if _shoelace(ring) > 0 else -1
        winding += sign * shapely.contains_xy(shapely.Polygon(ring), x, y)
    return winding


def near_contour(points: np.ndarray, offsets: np.ndarray, x: np.ndarray, y: np.ndarray,
                 tolerance: float = 1e-6) -> np.ndarray:
    """Points (x, y) within ``tolerance`` mm of any loop edge."""
    rings = [shapely.LinearRing(points[a:b]) for a, b in zip(offsets[:-1], offsets[1:]) if b - a >= 3]
    if not rings:
        return np.zeros(np.shape(x), dtype=bool)
    boundary = shapely.union_all(rings)
    return shapely.dwithin(boundary, shapely.points(x, y), tolerance)


def _shoelace(ring: np.ndarray) -> float:
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def random_ring_points(rng, rings: int) -> list[np.ndarray]:
    """The points ((k, 2) mm) of ``rings`` random star-shaped rings (3 to 300 points each) in a 100 mm square."""
    points = []
    for _ in range(rings):
        count = int(rng.integers(3, 300))
        angle = np.sort(rng.uniform(0, 2 * np.pi, count))
        radius = rng.uniform(0.5, 30.0) * rng.uniform(0.6, 1.0, count)
        centre = rng.uniform(-50, 50, 2)
        points.append(centre + np.column_stack([radius * np.cos(angle), radius * np.sin(angle)]))
    return points


def random_rings(rng, rings: int):
    """Edges of ``rings`` random star-shaped rings (:func:`random_ring_points`)."""
    points = random_ring_points(rng, rings)
    offsets = np.concatenate([[0], np.cumsum([len(ring) for ring in points])])
    return ring_edges(np.concatenate(points), offsets, list(range(rings)))


def brute_squared(qx, qy, edges):
    """(n, e) squared distance from every point to every edge, float64."""
    rx = qx[:, None] - edges.x[None, :]
    ry = qy[:, None] - edges.y[None, :]
    t = np.clip((rx * edges.vx + ry * edges.vy) * edges.inv_len2, 0.0, 1.0)
    return (rx - t * edges.vx) ** 2 + (ry - t * edges.vy) ** 2


def tree_of(edges):
    """The edge tree of RingEdges (:func:`heoslice.grading.search_kernels.edge_tree`)."""
    return edge_tree(edges.x, edges.y, edges.x + edges.vx, edges.y + edges.vy)


# --- Layers of rings on a 600 dpi grid, as the grading tests draw them -----------------------------------

PX = 25.4 / 600


def circle(radius: float, count: int = 720, center=(0.0, 0.0), clockwise: bool = False) -> np.ndarray:
    """(count, 2) polygon approximating a circle (sag below 1e-4 mm for the radii used)."""
    angle = np.linspace(0.0, 2 * np.pi, count, endpoint=False)
    ring = np.column_stack([center[0] + radius * np.cos(angle), center[1] + radius * np.sin(angle)])
    return ring[::-1] if clockwise else ring


def layer(*rings):
    """(points, offsets, signed areas, parents) of loops given outermost first; a ring's parent is the
    smallest earlier ring containing its first point."""
    points = np.concatenate(rings)
    offsets = np.concatenate([[0], np.cumsum([len(r) for r in rings])])
    area = np.array([shapely.Polygon(r).area * (1 if shapely.LinearRing(r).is_ccw else -1) for r in rings])
    parent = np.full(len(rings), -1)
    for i, ring in enumerate(rings):
        containing = [j for j in range(i) if shapely.Polygon(rings[j]).contains(shapely.Point(ring[0]))]
        if containing:
            parent[i] = min(containing, key=lambda j: abs(area[j]))
    return points, offsets, area, parent


def grid_around(half_mm: float) -> Grid:
    """A square grid of PX pixels centred on the origin, at least ``half_mm`` mm from it to every side."""
    cells = int(np.ceil(2 * half_mm / PX))
    return Grid(width=cells, height=cells, x_left=-cells * PX / 2, y_top=cells * PX / 2, px=PX, py=PX)


def pixel_centres(grid: Grid, box):
    """(x, y) mm of the centres of the pixels of ``box`` (rows r0:r1, columns c0:c1 of ``grid``), each (rows, cols)."""
    r0, r1, c0, c1 = box
    x = grid.x_left + (np.arange(c0, c1) + 0.5) * grid.px
    y = grid.y_top - (np.arange(r0, r1) + 0.5) * grid.py
    return np.meshgrid(x, y)


def rough_outline(seed: int, count: int = 900, radius: float = 6.0, amplitude: float = 0.6,
                  modes: int = 40) -> np.ndarray:
    """(count, 2) a star-shaped outline whose radius is a random sum of ``modes`` harmonics (mm): many
    shallow bumps, each a local minimum of the distance along the ring seen from inside."""
    rng = np.random.default_rng(seed)
    draws = np.array([(rng.normal(), rng.uniform(0.0, 2 * np.pi)) for _ in range(modes)])
    angle = np.linspace(0.0, 2 * np.pi, count, endpoint=False)
    mode = np.arange(2, modes + 2)[:, None]
    radius = radius + np.sum(amplitude * draws[:, :1] / (1 + mode / 4) * np.cos(mode * angle + draws[:, 1:]), axis=0)
    return np.column_stack([radius * np.cos(angle), radius * np.sin(angle)])


# Test-only references: straightforward forms of what the grading stage computes another way


def subregion_index(r: np.ndarray, count: int) -> np.ndarray:
    """Sub-region k in 1..N_R of positions r (r = 0 at the starting ring, 1 at the end): min(floor(r N_R) + 1, N_R)."""
    return np.clip(np.floor(np.asarray(r, dtype=np.float64) * count).astype(np.int64) + 1, 1, count)


def ring_weights(distances: np.ndarray) -> np.ndarray:
    """Eq. 10: weights of beta rings at n points from their distances ((n, beta) float, mm) -> (n, beta).

    w_i = prod_{k != i} d_k / sum_j prod_{k != j} d_k: the weights sum to 1, and a ring's
    weight is 1 on the ring itself (d_i = 0) and falls as the point moves away from it.
    Dividing through by prod_k d_k gives w_i = (1 / d_i) / sum_j (1 / d_j), computed here
    as (d_min / d_i) / sum_j (d_min / d_j), which neither overflows nor underflows; where
    some d_i are 0 those rings share the weight (one ring, unless rings touch).
    """
    d = np.asarray(distances, dtype=np.float64)
    if d.ndim != 2 or d.shape[1] < 1:
        raise ValueError("distances must be (n, beta) with beta >= 1")
    nearest = d.min(axis=1, keepdims=True)
    on_ring = d <= 0
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(on_ring, 0.0, nearest / d)
    ratio = np.where(nearest > 0, ratio, on_ring.astype(np.float64))
    return ratio / ratio.sum(axis=1, keepdims=True)


def ring_set(points: np.ndarray, offsets: np.ndarray, loops, encloses: bool) -> RingSet:
    """The ring set of some loops of a layer, with its edges and their bounding-box hierarchy."""
    edges = ring_edges(points, offsets, loops)
    return RingSet(tuple(loops), edges, encloses, LazyTree(edges))


def choose_materials(fractions: np.ndarray, solid: np.ndarray, layer: int,
                     origin: tuple[int, int] = (0, 0)) -> np.ndarray:
    """The material number each pixel jets: (rows, cols) int8, -1 where not solid.

    fractions: (K, rows, cols) float, each pixel's material fractions (summing to 1
    where solid; they are normalised here); solid: (rows, cols) bool.
    """
    fractions = np.asarray(fractions, dtype=np.float32)
    count = fractions.shape[0]
    if count == 0:
        raise ValueError("at least one material is needed")
    total = np.zeros(fractions.shape[1:], dtype=np.float32)
    for fraction in fractions:  # summed in order (numpy's pairwise sum would round differently)
        total += fraction
    threshold = thresholds(solid.shape, layer, origin) * np.where(total > 0, total, 1.0)
    chosen = np.full(solid.shape, count - 1, dtype=np.int8)
    running = np.zeros(solid.shape, dtype=np.float32)
    undecided = np.ones(solid.shape, dtype=bool)
    for material in range(count - 1):
        running += fractions[material]
        here = undecided & (threshold < running)
        chosen[here] = material
        undecided &= ~here
    chosen[~solid] = -1
    return chosen


def droplet_masks(fractions: np.ndarray, solid: np.ndarray, layer: int,
                  origin: tuple[int, int] = (0, 0)) -> np.ndarray:
    """One 1-bit mask per material: (K, rows, cols) bool, exactly one True per solid pixel, none elsewhere."""
    chosen = choose_materials(fractions, solid, layer, origin)
    return chosen[None, :, :] == np.arange(fractions.shape[0], dtype=np.int8)[:, None, None]


def paint_cells(regions, per_family: list[np.ndarray], dtype=np.float32) -> np.ndarray:
    """Per-pixel values over the layer box from per-cell values of each family ((cells_r, cells_c, c)).

    Each family's cells are expanded to its pixels (blocks of cell x cell) and written
    where the family's labels are: (rows, cols, c) of ``dtype``, 0 elsewhere.
    """
    channels = per_family[0].shape[-1] if per_family else 1
    b = regions.box
    out = np.zeros((b[1] - b[0], b[3] - b[2], channels), dtype=dtype)
    for field, cells, own in zip(regions.fields, per_family, family_of(regions)):
        r0, r1, c0, c1 = field.box
        f = field.lattice.cell
        pixels = np.repeat(np.repeat(cells.astype(dtype), f, axis=0), f, axis=1)[: r1 - r0, : c1 - c0]
        np.copyto(out[r0 - b[0]:r1 - b[0], c0 - b[2]:c1 - b[2]], pixels, where=own[..., None])
    return out


def in_process(*args) -> int:
    """Run the heoslice command line in this process (shares compiled kernels between tests); exit code."""
    from heoslice.cli import main

    try:
        main([str(a) for a in args])
    except SystemExit as done:
        return done.code if isinstance(done.code, int) else 0
    return 0


def heoslice(*args) -> subprocess.CompletedProcess:
    """Run the heoslice command line in a new process (stdin closed, 120 s at most); its outcome."""
    return subprocess.run([sys.executable, "-m", "heoslice", *map(str, args)], capture_output=True, text=True,
                          timeout=120, stdin=subprocess.DEVNULL)


def modules_loaded_by_command(args: list[str], modules: tuple[str, ...]) -> list[str]:
    """Which of ``modules`` a fresh process running ``heoslice --no-config *args`` has imported by its end
    (the command must succeed)."""
    script = ("import sys\nfrom heoslice.cli import main\n"
              f"sys.argv = ['heoslice', '--no-config', *{list(args)!r}]\n"
              "try:\n    main()\nfinally:\n"
              f"    print(sorted(m for m in {tuple(modules)!r} if m in sys.modules))\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return ast.literal_eval(done.stdout.strip().splitlines()[-1])


def stack_without_material_colours(source, target):
    """A copy of a droplet-mask stack directory whose manifest lists no materials (so none has a colour), as a
    hand-made or edited stack may."""
    target.mkdir()
    for item in source.iterdir():
        (target / item.name).write_bytes(item.read_bytes())
    manifest = json.loads((target / "manifest.json").read_text())
    manifest["grading"].pop("materials", None)
    (target / "manifest.json").write_text(json.dumps(manifest))
    return target


def brute_force_distance(points: np.ndarray, mesh) -> np.ndarray:
    """The literal nearest-surface distance, (n,) mm: min over all triangles of |p - closest point| with trimesh's own point-triangle routine."""
    import trimesh

    out = np.empty(len(points))
    triangles = mesh.triangles
    for i, p in enumerate(points):
        closest = trimesh.triangles.closest_point(triangles, np.repeat(p[None], len(triangles), axis=0))
        out[i] = np.linalg.norm(closest - p, axis=1).min()
    return out


# --- 3MF files written in the tests (the 3MF core and material XML) ---------------------------------------

CORE = "http://schemas.microsoft.com/3dmanufacturing/core/2015/02"
MATERIAL = "http://schemas.microsoft.com/3dmanufacturing/material/2015/02"
RELS = ('<?xml version="1.0" encoding="UTF-8"?><Relationships xmlns="http://schemas.openxmlformats.org/package/2006/'
        'relationships"><Relationship Target="/3D/3dmodel.model" Id="rel0" '
        'Type="http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel"/></Relationships>')


def mesh_xml(mesh, object_id: int, name: str, attributes: str = "", triangle=lambda i: "") -> str:
    """An <object> element holding ``mesh``; ``triangle(i)`` gives extra attributes of triangle i."""
    vertices = "".join(f'<vertex x="{x!r}" y="{y!r}" z="{z!r}"/>' for x, y, z in mesh.vertices.tolist())
    triangles = "".join(f'<triangle v1="{a}" v2="{b}" v3="{c}"{triangle(i)}/>'
                        for i, (a, b, c) in enumerate(mesh.faces.tolist()))
    return (f'<object id="{object_id}" type="model" name="{name}"{attributes}><mesh><vertices>{vertices}</vertices>'
            f'<triangles>{triangles}</triangles></mesh></object>')


def write_3mf(path, resources: str, build: str, unit: str = "millimeter", rels: bool = True) -> None:
    """A 3MF archive at ``path``: the model part holding ``resources`` and ``build`` (XML), with the package
    relationships unless ``rels`` is False."""
    model = (f'<?xml version="1.0" encoding="UTF-8"?><model unit="{unit}" xmlns="{CORE}" xmlns:m="{MATERIAL}">'
             f"<resources>{resources}</resources><build>{build}</build></model>")
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        if rels:
            archive.writestr("_rels/.rels", RELS)
        archive.writestr("3D/3dmodel.model", model)


def executed_on_simulator(job, get_layer) -> list:
    """Print ``job`` to a fresh simulated controller (fast link, no layer time) and return what it
    executed of it (its ExecutedLayer records, in order)."""
    from heoslice.printing import print_job
    from heoslice.printing.simulator import SimConfig, SimConnector, SimController

    controller = SimController(SimConfig(baud=100_000_000, layer_time_s=0.0, status_interval_s=0.2))
    try:
        print_job("sim://", job, get_layer, connector=SimConnector(controller))
        return [e for e in controller.executed if e.job_id == job.job_id]
    finally:
        controller.stop()


def lesion_distance(lesion: trimesh.Trimesh, points: np.ndarray, cap: float = np.inf) -> np.ndarray:
    """Brute-force distance (n,) from points (n, 3) to the lesion's surface: the least of trimesh's closest point on
    every triangle that can be nearest (one whose bounding sphere is no farther than the point's nearest vertex;
    the others cannot be); a point whose distance from the lesion's vertex centre less the lesion's radius about
    it is ``cap`` or more gets that lower bound instead (at least ``cap``)."""
    triangles = lesion.triangles
    centre = lesion.vertices.mean(axis=0)
    bound = np.linalg.norm(points - centre, axis=1) - np.linalg.norm(lesion.vertices - centre, axis=1).max()
    out = bound.copy()
    near = np.flatnonzero(bound < cap)
    middle = triangles.mean(axis=1)
    radius = np.linalg.norm(triangles - middle[:, None], axis=2).max(axis=1)
    for start in range(0, len(near), 2000):
        chunk = points[near[start:start + 2000]]
        upper = np.linalg.norm(chunk[:, None] - lesion.vertices[None], axis=2).min(axis=1)
        lower = np.linalg.norm(chunk[:, None] - middle[None], axis=2) - radius[None]
        point, triangle = np.nonzero(lower <= upper[:, None] + 1e-9)
        feet = trimesh.triangles.closest_point(triangles[triangle], chunk[point])
        distance = np.full(len(chunk), np.inf)
        np.minimum.at(distance, point, np.linalg.norm(chunk[point] - feet, axis=1))
        out[near[start:start + 2000]] = distance
    return out


#: A CT's two materials (soft tissue, bone) and the intensity curve between them, for the volume tests.
CT_MATERIALS = """
[materials.tissue]
color = "#f0a0a0"
channel = 1
[materials.bone]
color = "#ffffff"
channel = 2
"""
CT_CURVE = """
[intensity]
points = [ { value = 100, mix = { tissue = 1.0 } }, { value = 900, mix = { bone = 1.0 } } ]
"""
