"""Loading: one mesh file (PLY, STL, OBJ, OFF, 3MF) into the welded, checked, outward-oriented mesh heoslice slices.

Each format has its own reader returning a :class:`~heoslice.mesh.raw.RawMesh`: PLY,
OFF and binary STL are heoslice's strict readers; OBJ and ASCII STL are parsed by
trimesh. This module adds what a slicer needs on top: one-line errors naming the file,
vertices welded by coordinate (so STL soups share edges), degenerate faces dropped,
orientation made outward, per-vertex colour and the material fraction written by
``heoslice color``, and the warnings a lab should see (open, non-manifold, inverted,
metre-sized, degenerate). A 3MF is an assembly: each build item is prepared on its own
and becomes a part (:mod:`heoslice.mesh.assembly`).
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from heoslice.errors import InputError, shown
from heoslice.files import check_regular, open_regular, refuse_sparse
from heoslice.mesh.limits import MAX_MESH_BYTES
from heoslice.mesh.obj import read_with_trimesh
from heoslice.mesh.off import read_off
from heoslice.mesh.ply import check_ply_header, read_ply
from heoslice.mesh.raw import MATERIAL_PROPERTY, RawMesh
from heoslice.mesh.stl import read_binary_stl
from heoslice.mesh.topology import edge_groups, orient_outward, topology_notes
from heoslice.mesh.volume import face_volumes, shell_table, solid_volume_mm3
from heoslice.mesh.weld import duplicate_faces, weld_vertices

SUPPORTED_SUFFIXES = (".ply", ".stl", ".obj", ".off", ".3mf")

#: Largest coordinate magnitude accepted (1000 km in mm): beyond, squares of lengths overflow.
MAX_COORDINATE = 1e9


@dataclass(frozen=True)
class Mesh:
    """A loaded triangle mesh, welded and outward-oriented.

    vertices: (n, 3) float64, mm. faces: (m, 3) int64 indices into vertices,
    counter-clockwise seen from outside (right-hand rule normal points out).
    colors: (n, 3) uint8 per-vertex RGB, or None. material: (n,) float64 material
    fraction in [0, 1] (0 = M1, 1 = M2), or None. shell: (m,) int64 connected-shell
    label per face. warnings: human-readable notes about the input. color_source:
    'vertex' or 'face', what the file's colours were given for (face colours are
    spread to the vertices as the mean of the faces around each). duplicate_faces: how
    many faces repeated an earlier one and were dropped. part: (m,) int64 part label per face of an
    assembly (several files, a 3MF's objects), index into ``parts`` (:class:`heoslice.mesh.assembly.Part`),
    or None for a mesh of one file that is not an assembly. comments: the file's header comment lines (PLY),
    where ``heoslice color`` records the design (:class:`heoslice.material.design.Design`).
    """

    vertices: np.ndarray
    faces: np.ndarray
    colors: np.ndarray | None
    material: np.ndarray | None
    shell: np.ndarray
    source: Path
    sha256: str
    warnings: tuple[str, ...] = field(default=())
    color_source: str | None = None
    duplicate_faces: int = 0
    part: np.ndarray | None = None
    parts: tuple = ()
    comments: tuple[str, ...] = ()

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) float: [[x_min, y_min, z_min], [x_max, y_max, z_max]], mm."""
        return column_bounds(self.vertices)


def column_bounds(values: np.ndarray) -> np.ndarray:
    """(2, k) float: per-column minimum and maximum of (n, k) values, column by column
    (numpy's reduction of an (n, 3) array along axis 0 is slower than k contiguous ones)."""
    columns = range(values.shape[1])
    return np.array([[values[:, i].min() for i in columns], [values[:, i].max() for i in columns]])


def file_sha256(path: Path) -> str:
    """SHA-256 hex digest of a file's bytes, read in 1 MiB blocks."""
    digest = hashlib.sha256()
    with open_regular(path, "mesh") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _vertex_colors(raw: RawMesh) -> np.ndarray | None:
    """(n, 3) uint8 per-vertex RGB: the file's vertex colours, else the mean colour of the faces around each vertex."""
    if raw.vertex_colors is not None:
        return raw.vertex_colors
    if raw.face_colors is None:
        return None
    n = len(raw.vertices)
    corners = np.asarray(raw.faces).ravel()
    uses = np.maximum(np.bincount(corners, minlength=n), 1)
    sums = [np.bincount(corners, weights=np.repeat(raw.face_colors[:, c].astype(np.float64), 3), minlength=n)
            for c in range(3)]
    return np.clip(np.rint(np.column_stack(sums) / uses[:, None]), 0, 255).astype(np.uint8)


def load_mesh(path: str | os.PathLike, *, flat_ok: bool = False) -> Mesh:
    """Read, validate and prepare a mesh for slicing; raise InputError with one line if unusable.

    ``flat_ok`` (``info``): a mesh of zero height loads with a warning instead of being refused."""
    path = Path(path)
    status = check_regular(path, "mesh")
    if not os.access(path, os.R_OK):
        raise InputError(f"{path}: permission denied")
    suffix = path.suffix.lower()
    if suffix not in SUPPORTED_SUFFIXES:
        raise InputError(f"{path}: unsupported file type {suffix or '(none)'}; use PLY, STL, OBJ, OFF or 3MF")
    if status.st_size == 0:
        raise InputError(f"{path}: file is empty")
    if status.st_size > MAX_MESH_BYTES:
        raise InputError(f"{path}: mesh file of {status.st_size} bytes is larger than the {MAX_MESH_BYTES}-byte limit")
    refuse_sparse(path, status, "mesh")
    if suffix == ".3mf":
        from heoslice.mesh.assembly import load_3mf  # assembly builds on this module

        return load_3mf(path)
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=1) as hasher:  # hashing overlaps parsing (hashlib releases the GIL)
        digest = hasher.submit(file_sha256, path)
        return prepared_mesh(path, _read_raw(path, suffix), digest.result, flat_ok=flat_ok)


#: Magic bytes of files that are often renamed by mistake, and what they are.
_NOT_MESHES = ((b"\x89PNG\r\n\x1a\n", "a PNG image"), (b"\xff\xd8\xff", "a JPEG image"), (b"II*\x00", "a TIFF image"),
               (b"MM\x00*", "a TIFF image"), (b"GIF8", "a GIF image"), (b"%PDF", "a PDF document"),
               (b"PK\x03\x04", "a zip archive"), (b"\x1f\x8b", "a gzip archive"))


def _read_raw(path: Path, suffix: str) -> RawMesh:
    """The format reader's :class:`RawMesh` for a readable file with a supported suffix."""
    with open_regular(path, "mesh") as handle:
        magic = handle.read(8)
    kind = next((name for start, name in _NOT_MESHES if magic.startswith(start)), None)
    if kind:
        raise InputError(f"{path}: is {kind}, not a mesh (renamed to {suffix}?)")
    if suffix == ".ply":
        counts = check_ply_header(path)
        if counts.get("face", 0) == 0 and counts.get("tristrips", 0) == 0:
            raise InputError(f"{path}: the mesh has no faces")
        return read_ply(path)
    if suffix == ".stl" and (soup := read_binary_stl(path)) is not None:
        return soup
    if suffix == ".off":
        return read_off(path)
    return read_with_trimesh(path)


def prepared_mesh(path: Path, raw: RawMesh, sha256, *, flat_ok: bool = False) -> Mesh:
    """Check, weld, clean and orient a raw mesh; ``sha256`` is the file's digest, or a callable giving it when
    it is ready."""
    notes: list[str] = []
    vertices = np.asarray(raw.vertices)
    if vertices.dtype != np.float32:  # binary STL stays float32 until welded
        vertices = vertices.astype(np.float64, copy=False)
    faces = np.asarray(raw.faces, dtype=np.int64).reshape(-1, 3)
    if len(faces) == 0:
        raise InputError(f"{path}: the mesh has no faces")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise InputError(f"{path}: face indices outside the vertex list (0..{len(vertices) - 1})")
    reach = max(float(vertices.max(initial=0.0)), -float(vertices.min(initial=0.0)))  # NaN if any is NaN
    if not np.isfinite(reach):
        raise InputError(f"{path}: vertex coordinates contain NaN or infinite values")
    if reach > MAX_COORDINATE:
        raise InputError(f"{path}: vertex coordinates beyond +-{MAX_COORDINATE:g} (corrupt file, or wrong units)")
    colors = _vertex_colors(raw)
    material = raw.vertex_properties.get(MATERIAL_PROPERTY)
    if material is not None and len(material) == len(vertices):
        material = material.astype(np.float64)
        bad = np.flatnonzero(~np.isfinite(material))
        if len(bad):
            raise InputError(f"{path}: vertex {int(bad[0])}: '{MATERIAL_PROPERTY}' is {shown(material[bad[0]])}, "
                             f"not a number 0..1 ({len(bad)} vertices are NaN or infinite)")
        material = np.clip(material, 0.0, 1.0)
    else:
        material = None

    referenced = np.zeros(len(vertices), dtype=bool)
    referenced[faces.ravel()] = True
    if not referenced.all():
        used = np.flatnonzero(referenced)
        vertices, faces = vertices[used], np.searchsorted(used, faces)
    else:
        used = slice(None)
    vertices, faces, first = weld_vertices(vertices, faces)
    if colors is not None:
        colors = colors[used][first]
    if material is not None:
        material = material[used][first]
    repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
    if repeated.any():
        notes.append(f"{int(repeated.sum())} degenerate face(s) with repeated vertices were dropped")
        faces = faces[~repeated]
        if len(faces) == 0:
            raise InputError(f"{path}: every face is degenerate")
    low, high = column_bounds(vertices)
    extent = high - low
    if extent[2] <= 0:
        if not flat_ok:
            raise InputError(f"{path}: the mesh has zero height (flat in z); nothing to slice")
        notes.append("the mesh has zero height (flat in z): slice and color refuse it")
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=1) as beside:  # the volumes overlap the edge grouping (numpy releases the GIL)
        volumes = beside.submit(face_volumes, vertices, faces)
        groups = edge_groups(faces)
        duplicate = 0
        if not groups.winding_consistent:  # a repeated face walks its edges as the original: never in consistent meshes
            repeats = duplicate_faces(faces)
            duplicate = int(repeats.sum())
            if duplicate:  # repeated geometry would be sliced once per copy
                notes.append(f"{duplicate} duplicate face(s) repeating an earlier face were dropped")
                faces = faces[~repeats]
                volumes = beside.submit(face_volumes, vertices, faces)
                groups = edge_groups(faces)
        area, face_volume = volumes.result()
    zero_area = int((2.0 * area <= 1e-12 * max(float(extent.max()), 1.0) ** 2).sum())
    if zero_area:
        notes.append(f"{zero_area} zero-area face(s)")
    notes.extend(topology_notes(groups))
    faces, shell, orient_notes = orient_outward(vertices, faces, groups, face_volume)
    notes.extend(orient_notes)
    if extent.max() < 1.0:
        notes.append(_metres_note(float(extent.max())))
    return Mesh(vertices=vertices, faces=faces, colors=colors, material=material, shell=shell, source=path,
                sha256=sha256() if callable(sha256) else sha256, warnings=tuple(notes),
                color_source=raw.color_source if colors is not None else None,
                duplicate_faces=duplicate, comments=raw.comments)


_METRES_NOTE = "largest extent is "
#: Lowest height of a scaled part (1 nm), mm: below, planes and coordinates lose their precision.
_MIN_HEIGHT_MM = 1e-6


def _metres_note(extent: float) -> str:
    """The warning for a model whose largest extent (mm as read) is below 1."""
    return (f"{_METRES_NOTE}{extent:.4g}: the model looks like it is in metres; "
            "heoslice reads coordinates as mm (use --scale 1000)")


def _is_metres_note(note: str) -> bool:
    """Whether ``note`` is :func:`_metres_note`'s, of the whole model or of one part (``part 'NAME': ...``), which a
    scale settles: it is measured again on the scaled model."""
    return note.startswith(_METRES_NOTE) or (note.startswith("part ") and f": {_METRES_NOTE}" in note
                                              and note.endswith("(use --scale 1000)"))


def scaled(mesh: Mesh, factor: float) -> Mesh:
    """The same mesh with coordinates multiplied by ``factor`` (e.g. 1000 for metres to mm).

    The factor is range-checked before any arithmetic: the scaled coordinates stay
    within +-MAX_COORDINATE and the scaled part keeps a height.
    """
    if not (np.isfinite(factor) and factor > 0):
        raise InputError(f"scale: must be a positive number, got {factor:g}")
    low, high = column_bounds(mesh.vertices)
    reach = float(max(np.abs(low).max(), np.abs(high).max()))
    if reach > MAX_COORDINATE / factor:
        raise InputError(f"scale: {factor:g} takes coordinates to {reach:g} x {factor:g} mm, "
                         f"beyond +-{MAX_COORDINATE:g} mm")
    if float(high[2] - low[2]) * factor < _MIN_HEIGHT_MM:
        raise InputError(f"scale: {factor:g} makes the part {float(high[2] - low[2]) * factor:.3g} mm high, "
                         f"below {_MIN_HEIGHT_MM:g} mm")
    vertices = mesh.vertices * float(factor)
    notes = [note for note in mesh.warnings if not _is_metres_note(note)]
    low, high = column_bounds(vertices)
    extent = float((high - low).max())
    if extent < 1.0:
        notes.append(_metres_note(extent))
    return replace(mesh, vertices=vertices, warnings=tuple(notes))


def without_materials(mesh: Mesh) -> Mesh:
    """The same geometry with no colours or material fractions: a mesh sliced as one material."""
    return replace(mesh, colors=None, material=None, color_source=None)


def mesh_info(mesh: Mesh) -> dict:
    """Summary for ``heoslice info``: counts, bounding box (mm), watertight, winding, shells, volume.

    volume_mm3 is :func:`~heoslice.mesh.volume.solid_volume_mm3`, the volume ``verify --mesh``
    compares with (None when the mesh is not watertight); volume_exact says whether
    overlapping shells could be united.
    """
    groups = edge_groups(mesh.faces)
    uses = groups.uses
    watertight = bool(np.all(uses == 2))
    volume, exact = solid_volume_mm3(mesh) if watertight else (None, False)
    triangles, volumes, low, high = shell_table(mesh)
    shells = [{"number": number, "triangles": int(count), "volume_mm3": float(enclosed) if watertight else None,
               "bounds_mm": [lo, hi]}
              for number, (count, enclosed, lo, hi) in enumerate(zip(triangles.tolist(), volumes.tolist(),
                                                                      low.round(6).tolist(), high.round(6).tolist()))]
    return {
        "file": str(mesh.source),
        "sha256": mesh.sha256,
        "vertices": int(len(mesh.vertices)),
        "triangles": int(len(mesh.faces)),
        "bounds_mm": mesh.bounds.round(6).tolist(),
        "extent_mm": (mesh.bounds[1] - mesh.bounds[0]).round(6).tolist(),
        "watertight": watertight,
        "winding_consistent": groups.winding_consistent,
        "boundary_edges": int((uses == 1).sum()),
        "non_manifold_edges": int((uses > 2).sum()),
        "shells": int(mesh.shell.max() + 1) if len(mesh.shell) else 0,
        "duplicate_faces": mesh.duplicate_faces,
        "shell_list": shells,
        "volume_mm3": volume,
        "volume_exact": exact,
        "colors": mesh.colors is not None,
        "color_source": mesh.color_source,
        "material_fraction": mesh.material is not None,
        "warnings": list(mesh.warnings),
    }
