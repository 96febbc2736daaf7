"""Loading: read a triangle mesh (PLY, STL, OBJ, OFF) into arrays heoslice can slice.

Parsing is trimesh's; this module adds what a slicer needs on top: a PLY header
check that refuses hostile element counts before anything is allocated, one-line
errors naming the file, vertices welded by coordinate (so STL soups share edges),
faces with repeated vertices dropped, orientation made outward, per-vertex colour
and the material fraction written by ``heoslice color``, and the warnings a lab
should see (open, non-manifold, inverted, metre-sized, degenerate).
"""

from __future__ import annotations

import hashlib
import logging
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from heoslice.errors import InputError

SUPPORTED_SUFFIXES = (".ply", ".stl", ".obj", ".off")

#: Name of the per-vertex float property carrying the material fraction in [0, 1].
MATERIAL_PROPERTY = "material"

_PLY_TYPE_SIZES = {
    "char": 1, "int8": 1, "uchar": 1, "uint8": 1,
    "short": 2, "int16": 2, "ushort": 2, "uint16": 2,
    "int": 4, "int32": 4, "uint": 4, "uint32": 4, "float": 4, "float32": 4,
    "double": 8, "float64": 8,
}
_PLY_MAX_HEADER_BYTES = 1 << 16


@dataclass(frozen=True)
class Mesh:
    """A loaded triangle mesh, welded and outward-oriented.

    vertices: (n, 3) float64, mm. faces: (m, 3) int64 indices into vertices,
    counter-clockwise seen from outside (right-hand rule normal points out).
    colors: (n, 3) uint8 per-vertex RGB, or None. material: (n,) float64 material
    fraction in [0, 1] (0 = M1, 1 = M2), or None. shell: (m,) int64 connected-shell
    label per face. warnings: human-readable notes about the input.
    """

    vertices: np.ndarray
    faces: np.ndarray
    colors: np.ndarray | None
    material: np.ndarray | None
    shell: np.ndarray
    source: Path
    sha256: str
    warnings: tuple[str, ...] = field(default=())

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) float: [[x_min, y_min, z_min], [x_max, y_max, z_max]], mm."""
        return np.array([self.vertices.min(axis=0), self.vertices.max(axis=0)])


def file_sha256(path: Path) -> str:
    """SHA-256 hex digest of a file's bytes, read in 1 MiB blocks."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def check_ply_header(path: Path) -> dict[str, int]:
    """Parse a PLY header and refuse element counts the file cannot hold.

    Returns {element name: count}. Runs before any parser allocates for the body,
    so a header declaring 10**12 vertices in a small file fails at once.
    """
    size = path.stat().st_size
    with open(path, "rb") as handle:
        head = handle.read(_PLY_MAX_HEADER_BYTES)
    if not head.startswith(b"ply"):
        raise InputError(f"{path}: not a PLY file (no 'ply' magic line)")
    end = head.find(b"end_header")
    if end < 0:
        raise InputError(f"{path}: PLY header has no 'end_header' in its first 64 KiB")
    newline = head.find(b"\n", end)
    body_bytes = size - (newline + 1 if newline >= 0 else len(head))
    lines = head[:end].decode("ascii", errors="replace").splitlines()
    fmt = None
    elements: list[list] = []  # [name, count, min_row_bytes]
    for number, raw in enumerate(lines[1:], start=2):
        words = raw.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            if len(words) < 2 or words[1] not in ("ascii", "binary_little_endian", "binary_big_endian"):
                raise InputError(f"{path}: PLY header line {number}: unknown format {raw.strip()!r}")
            fmt = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise InputError(f"{path}: PLY header line {number}: bad element line {raw.strip()!r}")
            elements.append([words[1], int(words[2]), 0])
        elif words[0] == "property":
            if not elements:
                raise InputError(f"{path}: PLY header line {number}: property before any element")
            if len(words) >= 5 and words[1] == "list":
                count_type, item_type = words[2], words[3]
                if count_type not in _PLY_TYPE_SIZES or item_type not in _PLY_TYPE_SIZES:
                    raise InputError(f"{path}: PLY header line {number}: unknown property type in {raw.strip()!r}")
                elements[-1][2] += _PLY_TYPE_SIZES[count_type] if fmt != "ascii" else 2
            elif len(words) == 3 and words[1] in _PLY_TYPE_SIZES:
                elements[-1][2] += _PLY_TYPE_SIZES[words[1]] if fmt != "ascii" else 2
            else:
                raise InputError(f"{path}: PLY header line {number}: bad property line {raw.strip()!r}")
    if fmt is None:
        raise InputError(f"{path}: PLY header has no format line")
    needed = sum(count * max(row, 1) for _, count, row in elements)
    if needed > body_bytes:
        declared = ", ".join(f"{count} {name}" for name, count, _ in elements)
        raise InputError(
            f"{path}: truncated or corrupt PLY: the header declares {declared} "
            f"(at least {needed} bytes) but the body holds {body_bytes} bytes"
        )
    return {name: count for name, count, _ in elements}


def _read_trimesh(path: Path):
    """Let trimesh parse the file; any failure becomes one InputError line."""
    import trimesh

    logging.getLogger("trimesh").setLevel(logging.CRITICAL)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            loaded = trimesh.load(str(path), force="mesh", process=False)
    except Exception as err:  # trimesh raises many types for malformed files
        detail = " ".join(str(err).split())[:160] or type(err).__name__
        raise InputError(f"{path}: cannot be read as a mesh ({detail})") from err
    if not isinstance(loaded, trimesh.Trimesh):
        raise InputError(f"{path}: contains no triangle mesh")
    return loaded


def _ply_vertex_columns(loaded) -> dict[str, np.ndarray]:
    """The raw PLY vertex properties trimesh kept, as {name: (n,) array}; {} otherwise."""
    raw = loaded.metadata.get("_ply_raw") if hasattr(loaded, "metadata") else None
    if not raw or "vertex" not in raw:
        return {}
    data = raw["vertex"].get("data")
    if isinstance(data, dict):
        return {name: np.asarray(values) for name, values in data.items()}
    if getattr(data, "dtype", None) is not None and data.dtype.names:
        return {name: np.asarray(data[name]) for name in data.dtype.names}
    return {}


def _colors_from(loaded, columns: dict[str, np.ndarray], n: int) -> np.ndarray | None:
    """Per-vertex RGB as (n, 3) uint8, from PLY columns (uchar or float 0..1) or trimesh's visual."""
    if all(name in columns for name in ("red", "green", "blue")):
        rgb = np.stack([columns[name] for name in ("red", "green", "blue")], axis=1)
        if rgb.shape[0] != n:
            return None
        if np.issubdtype(rgb.dtype, np.floating):
            rgb = np.nan_to_num(rgb.astype(np.float64))
            if rgb.max(initial=0.0) <= 1.0:
                rgb = rgb * 255.0
            return np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
        return np.clip(rgb, 0, 255).astype(np.uint8)
    if getattr(loaded.visual, "kind", None) in ("vertex", "face"):
        return np.asarray(loaded.visual.vertex_colors)[:, :3].astype(np.uint8)
    return None


def _weld(vertices: np.ndarray, faces: np.ndarray):
    """Merge vertices with identical coordinates. Returns (unique_vertices, faces, first_index)."""
    unique, first, inverse = np.unique(vertices, axis=0, return_index=True, return_inverse=True)
    return unique, inverse.reshape(-1)[faces], first


def _orient_outward(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Make winding consistent and normals outward, shell by shell.

    Returns (faces, shell label per face, warnings). Trimesh finds the shells and
    fixes the winding; a closed shell whose volume is negative is turned inside out.
    """
    import trimesh

    notes: list[str] = []
    tm = trimesh.Trimesh(vertices, faces, process=False, validate=False)
    shell = np.zeros(len(faces), dtype=np.int64)
    labels = trimesh.graph.connected_component_labels(tm.face_adjacency, node_count=len(faces))
    shell[:] = labels
    if not tm.is_winding_consistent:
        trimesh.repair.fix_winding(tm)
        fixed = np.asarray(tm.faces)
        if np.any(fixed != faces):
            notes.append("inconsistent triangle winding was made consistent")
        faces = fixed
    # turn closed shells with negative signed volume inside out
    corner = vertices[faces]
    signed = np.einsum("ij,ij->i", corner[:, 0], np.cross(corner[:, 1], corner[:, 2])) / 6.0
    volume = np.bincount(shell, weights=signed)
    inverted = volume < 0
    if inverted.any():
        flip = inverted[shell]
        faces = faces.copy()
        faces[flip] = faces[flip][:, ::-1]
        notes.append(f"{int(inverted.sum())} shell(s) had inward-facing normals and were flipped")
    return faces, shell, notes


def load_mesh(path: str | os.PathLike) -> Mesh:
    """Read, validate and prepare a mesh for slicing; raise InputError with one line if unusable."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if path.is_dir():
        raise InputError(f"{path}: is a directory, not a mesh file")
    if not os.access(path, os.R_OK):
        raise InputError(f"{path}: permission denied")
    suffix = path.suffix.lower()
    if suffix not in SUPPORTED_SUFFIXES:
        raise InputError(f"{path}: unsupported file type {suffix or '(none)'}; use PLY, STL, OBJ or OFF")
    if path.stat().st_size == 0:
        raise InputError(f"{path}: file is empty")
    notes: list[str] = []
    if suffix == ".ply":
        counts = check_ply_header(path)
        if counts.get("face", 0) == 0:
            extra = " (only 'tristrips' elements; convert to triangles first)" if "tristrips" in counts else ""
            raise InputError(f"{path}: the mesh has no faces{extra}")
    loaded = _read_trimesh(path)
    vertices = np.asarray(loaded.vertices, dtype=np.float64)
    faces = np.asarray(loaded.faces, dtype=np.int64).reshape(-1, 3)
    if len(faces) == 0:
        raise InputError(f"{path}: the mesh has no faces")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise InputError(f"{path}: face indices outside the vertex list (0..{len(vertices) - 1})")
    if not np.isfinite(vertices).all():
        raise InputError(f"{path}: vertex coordinates contain NaN or infinite values")
    columns = _ply_vertex_columns(loaded)
    colors = _colors_from(loaded, columns, len(vertices))
    material = None
    if MATERIAL_PROPERTY in columns and len(columns[MATERIAL_PROPERTY]) == len(vertices):
        material = np.clip(np.nan_to_num(columns[MATERIAL_PROPERTY].astype(np.float64)), 0.0, 1.0)

    used = np.unique(faces)
    vertices, faces, first = _weld(vertices[used], np.searchsorted(used, faces))
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
    extent = vertices.max(axis=0) - vertices.min(axis=0)
    if extent[2] <= 0:
        raise InputError(f"{path}: the mesh has zero height (flat in z); nothing to slice")
    area = np.linalg.norm(np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]],
                                   vertices[faces[:, 2]] - vertices[faces[:, 0]]), axis=1)
    zero_area = int((area <= 1e-12 * max(float(extent.max()), 1.0) ** 2).sum())
    if zero_area:
        notes.append(f"{zero_area} zero-area face(s)")
    faces, shell, orient_notes = _orient_outward(vertices, faces)
    notes.extend(orient_notes)
    if extent.max() < 1.0:
        notes.append(
            f"largest extent is {extent.max():.4g}: the model looks like it is in metres; "
            "heoslice reads coordinates as mm (use --scale 1000)"
        )
    return Mesh(
        vertices=vertices,
        faces=faces,
        colors=colors,
        material=material,
        shell=shell,
        source=path,
        sha256=file_sha256(path),
        warnings=tuple(notes),
    )


def scaled(mesh: Mesh, factor: float) -> Mesh:
    """The same mesh with coordinates multiplied by ``factor`` (e.g. 1000 for metres to mm)."""
    from dataclasses import replace

    if not factor > 0:
        raise InputError(f"scale must be positive, got {factor}")
    return replace(mesh, vertices=mesh.vertices * float(factor))


def mesh_info(mesh: Mesh) -> dict:
    """Summary for ``heoslice info``: counts, bounding box (mm), watertight, winding, shells, volume."""
    import trimesh

    tm = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False, validate=False)
    edges = np.sort(mesh.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, uses = np.unique(edges, axis=0, return_counts=True)
    watertight = bool(np.all(uses == 2))
    return {
        "file": str(mesh.source),
        "sha256": mesh.sha256,
        "vertices": int(len(mesh.vertices)),
        "triangles": int(len(mesh.faces)),
        "bounds_mm": mesh.bounds.round(6).tolist(),
        "extent_mm": (mesh.bounds[1] - mesh.bounds[0]).round(6).tolist(),
        "watertight": watertight,
        "winding_consistent": bool(tm.is_winding_consistent),
        "boundary_edges": int((uses == 1).sum()),
        "non_manifold_edges": int((uses > 2).sum()),
        "shells": int(mesh.shell.max() + 1) if len(mesh.shell) else 0,
        "volume_mm3": float(tm.volume) if watertight else None,
        "colors": mesh.colors is not None,
        "material_fraction": mesh.material is not None,
        "warnings": list(mesh.warnings),
    }
