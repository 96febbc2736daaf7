"""Assemblies: several parts (mesh files, the objects of a 3MF) as one mesh whose faces remember their part.

A lab's model often comes as one file per segment (organ, lesion, vessels) or as a 3MF with
one object per material. Each part is loaded and prepared on its own (welded, checked and
oriented outward by :mod:`heoslice.mesh.load`), so no edge is shared between parts and every
contour loop cut from the assembly belongs to one part; the parts are then concatenated and
each face is labelled with its part (:attr:`Mesh.part`).
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from heoslice.errors import InputError
from heoslice.mesh.load import Mesh, file_sha256, load_mesh, prepared_mesh
from heoslice.mesh.threemf import read_3mf
from heoslice.mesh.volume import signed_volume_mm3


@dataclass(frozen=True)
class Part:
    """One part of an assembly: its name (a file's stem, a 3MF object's name), the file it came from and that
    file's SHA-256, its volume (mm^3, enclosed by its outward faces), its one colour (r, g, b) when every vertex
    has the same colour (else None), and the one material its file names for it (a 3MF base material), if any."""

    name: str
    source: Path
    sha256: str
    volume_mm3: float
    color: tuple[int, int, int] | None = None
    material_name: str | None = None


def uniform_color(mesh: Mesh) -> tuple[int, int, int] | None:
    """The mesh's colour when all its vertices have the same one, else None (no colours, or several)."""
    if mesh.colors is None or not len(mesh.colors):
        return None
    first = mesh.colors[0]
    return tuple(int(v) for v in first) if bool(np.all(mesh.colors == first)) else None


def part_of(mesh: Mesh, name: str, material_name: str | None = None) -> Part:
    """The :class:`Part` record of one prepared mesh."""
    return Part(name=name, source=mesh.source, sha256=mesh.sha256,
                volume_mm3=abs(signed_volume_mm3(mesh.vertices, mesh.faces)), color=uniform_color(mesh),
                material_name=material_name)


def assemble(meshes: Sequence[Mesh], source: Path, sha256: str) -> Mesh:
    """One mesh of ``meshes``, each prepared on its own, its faces labelled with their part (:attr:`Mesh.part`).

    A mesh that is an assembly already (a 3MF) brings its parts; any other is one part named by its
    file's stem. Colours (and material fractions) are kept when every mesh has them; shells are
    numbered through the meshes; a one-part mesh's warnings are prefixed with its part's name.
    """
    if not meshes:
        raise InputError("parts: no parts to assemble")
    parts, labels, notes = [], [], []
    for mesh in meshes:
        own = mesh.parts or (part_of(mesh, mesh.source.stem),)
        labels.append(len(parts) + (mesh.part if mesh.part is not None else np.zeros(len(mesh.faces), np.int64)))
        notes += list(mesh.warnings) if mesh.parts else [f"part {own[0].name!r}: {note}" for note in mesh.warnings]
        parts += own
    starts = np.cumsum([0] + [len(mesh.vertices) for mesh in meshes[:-1]])
    shell_starts = np.cumsum([0] + [int(mesh.shell.max()) + 1 if len(mesh.shell) else 0 for mesh in meshes[:-1]])
    colors = None
    if all(mesh.colors is not None for mesh in meshes):
        colors = np.concatenate([mesh.colors for mesh in meshes])
    material = None
    if all(mesh.material is not None for mesh in meshes):
        material = np.concatenate([mesh.material for mesh in meshes])
    kinds = {mesh.color_source for mesh in meshes}
    return Mesh(
        vertices=np.concatenate([np.asarray(mesh.vertices, dtype=np.float64) for mesh in meshes]),
        faces=np.concatenate([mesh.faces + start for mesh, start in zip(meshes, starts)]),
        colors=colors, material=material,
        shell=np.concatenate([mesh.shell + start for mesh, start in zip(meshes, shell_starts)]),
        source=source, sha256=sha256, warnings=tuple(notes),
        color_source=kinds.pop() if colors is not None and len(kinds) == 1 else None,
        duplicate_faces=sum(mesh.duplicate_faces for mesh in meshes),
        part=np.concatenate(labels), parts=tuple(parts),
    )


def read_3mf_parts(path: Path, sha256: str) -> tuple[list[Mesh], list[Part]]:
    """Each build item of a 3MF file as a prepared mesh and its :class:`Part` (named by its object; its
    material name when all its triangles have the same base material or colour)."""
    model = read_3mf(path)
    meshes, parts = [], []
    for item in model.objects:
        try:
            mesh = prepared_mesh(path, item.mesh, sha256)
        except InputError as err:
            problem = str(err).removeprefix(f"{path}: ")
            raise InputError(f"{path}: 3MF object {item.name!r}: {problem}", exit_code=err.exit_code) from None
        used = np.unique(item.face_material)
        material_name = model.materials[int(used[0])].name if len(used) == 1 and used[0] >= 0 else None
        meshes.append(mesh)
        parts.append(part_of(mesh, item.name, material_name))
    return meshes, parts


def load_3mf(path: Path) -> Mesh:
    """A 3MF file as one mesh, each build item a part (:func:`read_3mf_parts`)."""
    sha256 = file_sha256(path)
    meshes, parts = read_3mf_parts(path, sha256)
    meshes = [replace(mesh, part=np.zeros(len(mesh.faces), np.int64), parts=(part,))
              for mesh, part in zip(meshes, parts)]
    return meshes[0] if len(meshes) == 1 else assemble(meshes, path, sha256)


def load_assembly(paths: Sequence[Path]) -> Mesh:
    """Every file of ``paths`` as the parts of one mesh (:func:`assemble`). One file is that file's mesh, with
    its parts labelled; several are named by their files joined by '+', and their SHA-256 is that of one
    ``SHA256  NAME`` line per file (as sha256sum prints them)."""
    meshes = [load_mesh(path) for path in paths]
    if len(meshes) == 1 and meshes[0].parts:
        return meshes[0]
    if len(meshes) == 1:
        return assemble(meshes, meshes[0].source, meshes[0].sha256)
    listing = "".join(f"{mesh.sha256}  {mesh.source.name}\n" for mesh in meshes)
    source = Path("+".join(mesh.source.name for mesh in meshes))
    return assemble(meshes, source, hashlib.sha256(listing.encode()).hexdigest())
