"""Colouring a mesh by a material distribution function (paper section III.A, Fig. 2).

The paper's Z-axis modelling steps, on a loaded :class:`~heoslice.mesh.Mesh`:
(1) bounding box, (2) every vertex RGB starts at (0, 0, 0), (3) the reference feature,
(4) r and f(r) per vertex, blended from M1 to M2 by eq. 1, (5) the PLY written back.
Optionally the mesh is first subdivided so no edge is longer than ``max_edge`` mm (a
function with fine detail is then not undersampled at sparse vertices), and whole
shells can be given their own material.

The PLY carries per-vertex uchar red/green/blue and the exact fraction f clipped to
[0, 1] as the float vertex property ``material`` (:data:`heoslice.mesh.MATERIAL_PROPERTY`),
so later stages need not invert colours. Header comments record what was done::

    comment heoslice color: linear: f = 1*r + 0
    comment heoslice reference: plane through (0, 0, 0) with normal (0, 0, 1)
    comment heoslice material M1 M1 240,240,240 channel 1
    comment heoslice material M2 M2 0,255,0 channel 2
    comment heoslice shell 1 tumour 255,0,0 channel 3

and, as the machine-readable record ``slice`` follows, the :class:`~heoslice.material.design.Design` (its
``heoslice design 1 ...`` lines: materials and roles, reference, function, r normalisation, shells).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from heoslice.errors import InputError, OutputError, shown
from heoslice.files import check_output, head_bytes, write_output
from heoslice.material.design import Design, ReferenceRecord
from heoslice.material.functions import DistributionFunction, evaluate, make_function
from heoslice.material.materials import DEFAULT_MATERIALS, Material, blend, to_rgb8
from heoslice.material.references import (
    REFERENCES,
    Reference,
    make_reference,
    normalise,
    reference_distance,
)
from heoslice.mesh import MATERIAL_PROPERTY, Mesh, load_mesh, shell_labels

#: Subdivision refuses to make more triangles than this (memory: about 1 KB each on the way).
MAX_SUBDIVIDED_TRIANGLES = 20_000_000
#: The shortest edge length subdivision is asked for (a nanometre; shorter ones overflow the estimate).
MIN_MAX_EDGE_MM = 1e-6


@dataclass(frozen=True)
class ColorSpec:
    """What to colour with: function, reference (kind and its optional geometry), range, materials.

    at / normal / direction: (3,) mm or unit vectors, None for the defaults of
    :func:`heoslice.material.references.make_reference`. surface: a second mesh (or its path) for
    ``reference='surface'``; surface_scale: how much that mesh's file coordinates were multiplied by (``color
    --scale``), recorded with it so that ``slice`` reads the file at the same size. r_range: (R0, R1) mm, None = 0 .. largest distance.
    shell_materials: ((shell number, Material), ...): those shells are coloured whole with
    that material, and their material fraction is 1 (the shell is its own target material).
    """

    function: DistributionFunction = field(default_factory=lambda: make_function("linear"))
    reference: str = "plane"
    at: tuple[float, float, float] | None = None
    normal: tuple[float, float, float] | None = None
    direction: tuple[float, float, float] | None = None
    surface: Path | Mesh | None = None
    surface_scale: float = 1.0
    r_range: tuple[float, float] | None = None
    m1: Material = DEFAULT_MATERIALS["M1"]
    m2: Material = DEFAULT_MATERIALS["M2"]
    max_edge: float | None = None
    shell_materials: tuple[tuple[int, Material], ...] = ()


@dataclass(frozen=True, eq=False)
class ColoredMesh:
    """A coloured mesh ready to write.

    vertices (n, 3) float64 mm; faces (m, 3) int64; colors (n, 3) uint8; material (n,)
    float64 fraction of M2 in [0, 1], exactly representable as float32 (what the PLY
    stores); r (n,) float64 normalised distance; vertex_shell (n,) int64; comments: PLY
    header comment lines.
    """

    vertices: np.ndarray
    faces: np.ndarray
    colors: np.ndarray
    material: np.ndarray
    r: np.ndarray
    vertex_shell: np.ndarray
    reference: Reference
    comments: tuple[str, ...] = ()
    design: Design | None = None


def subdivide(vertices: np.ndarray, faces: np.ndarray, max_edge: float) -> tuple[np.ndarray, np.ndarray]:
    """Split triangles (trimesh.remesh.subdivide_to_size) until no edge is longer than max_edge mm.

    Raises InputError if max_edge is not positive or the result would exceed
    :data:`MAX_SUBDIVIDED_TRIANGLES` triangles.
    """
    from trimesh.remesh import subdivide_to_size

    if not (isinstance(max_edge, (int, float)) and math.isfinite(max_edge) and max_edge >= MIN_MAX_EDGE_MM):
        raise InputError(f"max_edge: must be a positive length of at least {MIN_MAX_EDGE_MM:g} mm, "
                         f"got {shown(max_edge)}")
    corners = vertices[faces]
    longest = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
    halvings = np.ceil(np.log2(np.maximum(longest / max_edge, 1.0)))
    estimate = float(np.sum(4.0 ** halvings))
    if estimate > MAX_SUBDIVIDED_TRIANGLES:
        raise InputError(f"max_edge: {max_edge:g} mm would make about {estimate:.3g} triangles "
                         f"(limit {MAX_SUBDIVIDED_TRIANGLES:.3g}); choose a larger value")
    new_vertices, new_faces = subdivide_to_size(vertices, faces, max_edge=max_edge,
                                                max_iter=int(halvings.max(initial=0)) + 2)
    return np.asarray(new_vertices, dtype=np.float64), np.asarray(new_faces, dtype=np.int64)


def _canonical(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices welded and sorted by coordinate, as :func:`heoslice.mesh.load_mesh` orders them,
    so a written mesh reads back vertex for vertex."""
    unique, inverse = np.unique(vertices, axis=0, return_inverse=True)
    return unique, inverse.reshape(-1)[faces]


def _vertex_shells(faces: np.ndarray, shell: np.ndarray, count: int) -> np.ndarray:
    """Shell number (count,) of each vertex: that of its faces (the largest where shells touch)."""
    out = np.zeros(count, dtype=np.int64)
    np.maximum.at(out, faces.ravel(), np.repeat(shell, 3))
    return out


def material_comment(prefix: str, material: Material) -> str:
    """``heoslice material M1 gel 240,240,240 channel 1`` (the role, name, colour, channel)."""
    channel = "-" if material.channel is None else str(material.channel)
    name = material.name.replace(" ", "_") or "-"
    return f"heoslice {prefix} {name} {','.join(map(str, material.color))} channel {channel}"


def color_mesh(mesh: Mesh, spec: ColorSpec, progress: Callable[[int, int], None] | None = None) -> ColoredMesh:
    """Colour every vertex of ``mesh`` by ``spec`` (the paper's steps 1-4); nothing is written.

    Raises InputError naming the :class:`ColorSpec` field at fault (``shell_materials``,
    ``max_edge``, ``surface``, ``reference``, ``at``, ``normal``, ``direction``, ``r_range``,
    ``expression``) for a shell number the mesh does not have, a subdivision that is too
    fine, an unreadable reference mesh, a range of zero width, or an expression undefined
    at some r. ``progress(done, total)`` follows the distance computation (vertices).
    """
    if spec.reference not in REFERENCES:
        raise InputError(f"reference: unknown reference {spec.reference!r} (choose from {', '.join(REFERENCES)})")
    vertices, faces, shell = mesh.vertices, mesh.faces, mesh.shell
    shell_count = int(shell.max()) + 1 if len(shell) else 0
    for number, _ in spec.shell_materials:
        if not 0 <= number < shell_count:
            raise InputError(f"shell_materials: shell {number} does not exist: the mesh has {shell_count} "
                             f"shell(s), numbered 0..{shell_count - 1}")
    if spec.max_edge is not None:
        vertices, faces = _canonical(*subdivide(vertices, faces, spec.max_edge))
        shell = shell_labels(faces)
    surface, surface_source = None, None
    if spec.reference == "surface":
        if spec.surface is None:
            raise InputError("surface: a surface reference needs a second mesh: every vertex of the model "
                             "lies on the model's own surface, at distance 0")
        try:
            other = spec.surface if isinstance(spec.surface, Mesh) else load_mesh(spec.surface)
        except InputError as err:
            raise InputError(f"surface: {err}") from None
        surface = (other.vertices, other.faces)
        surface_source = (str(Path(other.source).resolve()), other.sha256)
    reference = make_reference(spec.reference, vertices, faces, at=spec.at, normal=spec.normal,
                               direction=spec.direction, surface=surface)
    colors = np.zeros((len(vertices), 3), dtype=np.uint8)  # step 2: every vertex starts at (0, 0, 0)
    distance = reference_distance(reference, vertices, progress)
    r = normalise(distance, spec.r_range)
    r_range = spec.r_range if spec.r_range is not None else (0.0, float(distance.max(initial=0.0)))
    f = evaluate(spec.function, r)
    fraction = np.clip(f, 0.0, 1.0).astype(np.float32).astype(np.float64)
    colors[:] = to_rgb8(blend(spec.m1, spec.m2, fraction))
    vertex_shell = _vertex_shells(faces, shell, len(vertices))
    comments = [f"heoslice color: {spec.function.describe()}", f"heoslice reference: {reference.describe()}",
                material_comment("material M1", spec.m1), material_comment("material M2", spec.m2)]
    for number, material in spec.shell_materials:
        mine = vertex_shell == number
        colors[mine] = material.color
        fraction[mine] = 1.0
        comments.append(material_comment(f"shell {number}", material))
    design = Design(spec.m1, spec.m2, _reference_record(reference, surface_source, spec.surface_scale), spec.function,
                    (float(r_range[0]), float(r_range[1])), "max" if spec.r_range is None else "range",
                    tuple(spec.shell_materials))
    comments.extend(design.to_header())
    return ColoredMesh(vertices, faces, colors, fraction, r, vertex_shell, reference, tuple(comments), design)


def _reference_record(reference: Reference, surface_source: tuple[str, str] | None,
                      surface_scale: float = 1.0) -> ReferenceRecord:
    """The design's record of a resolved reference (a surface by its mesh's absolute path and SHA-256, and the
    factor its file's coordinates were multiplied by)."""
    if reference.kind == "surface":
        if surface_source is None:
            return ReferenceRecord("surface")
        return ReferenceRecord("surface", surface=surface_source[0], surface_sha256=surface_source[1],
                               surface_scale=surface_scale)
    return ReferenceRecord(reference.kind, reference.point, reference.direction)


def _coordinate_type(vertices: np.ndarray) -> tuple[str, str]:
    """('float', '<f4') when every coordinate survives float32 exactly, else ('double', '<f8')."""
    if np.array_equal(vertices.astype(np.float32).astype(np.float64), vertices):
        return "float", "<f4"
    return "double", "<f8"


def ply_bytes(colored: ColoredMesh, ascii: bool = False) -> bytes:
    """The PLY file: vertices x y z, uchar red green blue, float ``material``; faces as vertex lists.

    Coordinates are written as float when that is exact, else double; the ASCII form
    prints 9 significant digits for float and 17 for double, so reading back is exact.
    """
    ply_type, numpy_type = _coordinate_type(colored.vertices)
    n, m = len(colored.vertices), len(colored.faces)
    header = ["ply", f"format {'ascii' if ascii else 'binary_little_endian'} 1.0"]
    header += [f"comment {' '.join(line.split())}" for line in colored.comments]
    header += [f"element vertex {n}"] + [f"property {ply_type} {axis}" for axis in "xyz"]
    header += [f"property uchar {c}" for c in ("red", "green", "blue")]
    header += [f"property float {MATERIAL_PROPERTY}", f"element face {m}",
               "property list uchar int vertex_indices", "end_header"]
    # a PLY header is ASCII: a comment's other characters (a material named in any script) as backslash escapes
    head = ("\n".join(header) + "\n").encode("ascii", "backslashreplace")
    if ascii:
        coordinate = "%.9g" if ply_type == "float" else "%.17g"
        table = np.column_stack([colored.vertices, colored.colors.astype(np.float64),
                                 colored.material.astype(np.float32).astype(np.float64)])
        vertex_text = (f"{coordinate} {coordinate} {coordinate} %d %d %d %.9g\n" * n) % tuple(table.ravel().tolist())
        face_text = ("3 %d %d %d\n" * m) % tuple(colored.faces.ravel().tolist())
        return head + vertex_text.encode("ascii") + face_text.encode("ascii")
    vertex = np.empty(n, dtype=[("x", numpy_type), ("y", numpy_type), ("z", numpy_type),
                                ("red", "u1"), ("green", "u1"), ("blue", "u1"), (MATERIAL_PROPERTY, "<f4")])
    for i, axis in enumerate("xyz"):
        vertex[axis] = colored.vertices[:, i]
    for i, channel in enumerate(("red", "green", "blue")):
        vertex[channel] = colored.colors[:, i]
    vertex[MATERIAL_PROPERTY] = colored.material
    face = np.empty(m, dtype=[("count", "u1"), ("index", "<i4", (3,))])
    face["count"] = 3
    face["index"] = colored.faces
    return head + vertex.tobytes() + face.tobytes()


def is_colored_ply(path: Path) -> bool:
    """Whether ``path`` is a PLY ``heoslice color`` wrote (its header records the function): the only
    existing file ``color --force`` replaces."""
    head = head_bytes(path)
    return head.startswith(b"ply") and b"\ncomment heoslice color: " in head.split(b"end_header", 1)[0]


def write_ply(path: Path, colored: ColoredMesh, ascii: bool = False, force: bool = False,
              inputs: tuple[Path, ...] = ()) -> Path:
    """Write ``colored`` to ``path`` under the output rule (:func:`heoslice.files.check_output`): atomically,
    never over ``inputs``, a link or a file heoslice did not write (even with ``force``).

    Raises OutputError if the file exists (unless ``force``) or cannot be written; a
    failed write leaves nothing behind.
    """
    path = Path(path)
    check_output(path, "coloured PLY", force=force, made_here=is_colored_ply, inputs=inputs)
    if path.suffix.lower() != ".ply":
        raise OutputError(f"{path}: the output must be a .ply file")
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise OutputError(f"{path}: the folder {folder} does not exist")
    return write_output(path, ply_bytes(colored, ascii=ascii))


def default_output(model: Path, function: DistributionFunction) -> Path:
    """Where ``heoslice color`` writes without -o: beside the model, ``<stem>_<function>.ply``."""
    model = Path(model)
    return model.with_name(f"{model.stem}_{function.kind}.ply")
