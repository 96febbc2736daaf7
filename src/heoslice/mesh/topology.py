"""Mesh topology from one counting sort of the edges: shells, edge use counts, winding consistency, orientation."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from heoslice.jit import i64
from heoslice.mesh.topology_kernels import _edge_runs, _lowest_connected
from heoslice.mesh.volume import face_volumes, winding_number


@dataclass(frozen=True)
class EdgeGroups:
    """The faces' edges (3 per face, face f's at 3f..3f+2) sorted by undirected edge.

    ``order`` ((3m,) int) sorts them; ``starts`` ((e,) int) is where each distinct
    edge's run begins in that order; ``forward`` ((3m,) bool, sorted) is True where the
    face walks the edge from its lower to its higher vertex index. Shells, edge use
    counts and winding consistency all come from this one sort.
    """

    order: np.ndarray
    starts: np.ndarray
    forward: np.ndarray

    @functools.cached_property
    def uses(self) -> np.ndarray:
        """(e,) int: faces using each distinct edge (1 on a hole's rim, more than 2 if non-manifold)."""
        return np.diff(np.append(self.starts, len(self.order)))

    @functools.cached_property
    def winding_consistent(self) -> bool:
        """No edge is walked twice in the same direction (neighbouring faces agree on orientation)."""
        forward = np.add.reduceat(self.forward.astype(np.int64), self.starts) if len(self.starts) else 0
        return bool(np.all(forward <= 1) and np.all(self.uses - forward <= 1))


def edge_groups(faces: np.ndarray) -> EdgeGroups:
    """Group the faces' edges by undirected edge, in order of (lower, higher) vertex, each group's edges in
    index order (compiled: a counting sort by lower vertex). Indices far beyond the faces' own count are
    renumbered first, in the same order, so the sort's buckets stay as few as the vertices used."""
    faces = i64(faces)
    vertices = int(faces.max(initial=-1)) + 1
    if vertices > 3 * len(faces) + 1:
        used, inverse = np.unique(faces, return_inverse=True)
        faces, vertices = i64(inverse.reshape(faces.shape)), len(used)
    order, starts, forward = _edge_runs(faces, vertices)
    return EdgeGroups(order=order, starts=starts, forward=forward)


def shell_labels(faces: np.ndarray, groups: EdgeGroups | None = None) -> np.ndarray:
    """(m,) int: connected shell of each face, faces being connected through shared edges.

    Shells are numbered in the order of their first face (as scipy's connected
    components): each face is joined to the faces it shares an edge with by a compiled
    union-find whose roots are the shells' first faces (:mod:`heoslice.mesh.topology_kernels`),
    not scipy.sparse.csgraph, whose import costs every slice more than the labelling
    (benchmarks/README.md).
    """
    groups = groups if groups is not None else edge_groups(faces)
    same = np.ones(len(groups.order), dtype=bool)
    same[groups.starts] = False  # entry i shares its edge with entry i - 1 in sorted order
    owner = groups.order // 3
    a, b = owner[:-1][same[1:]], owner[1:][same[1:]]
    label = _lowest_connected(i64(a), i64(b), len(faces))
    return (np.cumsum(label == np.arange(len(faces))) - 1)[label]


def edge_use_counts(faces: np.ndarray) -> np.ndarray:
    """How many faces use each distinct undirected edge ((e,) int)."""
    return edge_groups(faces).uses


def topology_notes(groups: EdgeGroups) -> list[str]:
    """Warnings for edges used by one face (holes: the mesh is open) or by more than two (non-manifold)."""
    uses = groups.uses
    notes = []
    boundary, shared = int((uses == 1).sum()), int((uses > 2).sum())
    if boundary:
        notes.append(f"open mesh: {boundary} boundary edge(s); slices are closed where the surface has holes")
    if shared:
        notes.append(f"non-manifold: {shared} edge(s) shared by more than two faces")
    return notes


def orient_outward(vertices: np.ndarray, faces: np.ndarray, groups: EdgeGroups,
                    face_volume: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Make winding consistent and orientation outward where that is unambiguous.

    Returns (faces, shell label per face, warnings). Inconsistent winding is fixed by
    trimesh. A mesh whose total signed volume is negative is inverted as a whole. A
    shell with negative volume that no other shell encloses is turned inside out; one
    enclosed by another shell is a cavity and stays as it is (a nested shell with
    positive volume, such as a lesion inside an organ, is solid and also stays).
    """
    notes: list[str] = []
    shell = shell_labels(faces, groups)
    if not groups.winding_consistent:
        import trimesh

        mesh = trimesh.Trimesh(vertices, faces, process=False, validate=False)
        trimesh.repair.fix_winding(mesh)
        fixed = np.asarray(mesh.faces, dtype=np.int64)
        if np.any(fixed != faces):
            notes.append("inconsistent triangle winding was made consistent")
        faces = fixed
        face_volume = face_volumes(vertices, faces)[1]
    volume = np.bincount(shell, weights=face_volume)
    if volume.sum() < 0:
        notes.append("normals pointed inward (negative volume); the mesh was turned inside out")
        return faces[:, ::-1].copy(), shell, notes
    flip = np.zeros(len(volume), dtype=bool)
    for label in np.nonzero(volume < 0)[0]:  # one winding query per inverted shell, not per face
        probe = vertices[faces[shell == label][0, 0]]
        others = vertices[faces[shell != label]]
        flip[label] = abs(winding_number(probe, others)) < 0.5
    if flip.any():
        faces = faces.copy()
        faces[flip[shell]] = faces[flip[shell]][:, ::-1]
        notes.append(f"{int(flip.sum())} shell(s) had inward-facing normals and were flipped")
    return faces, shell, notes

