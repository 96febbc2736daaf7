"""3MF reading: objects with their names, base materials and colour groups, read by heoslice itself.

A 3MF file is a zip archive whose model part (``3D/3dmodel.model``, or the part named by
the package relationships) is XML in the 3MF core namespace. Geometry is placed as
trimesh places it: every build item is its object (components resolved) under the
item's transform, in the model's unit converted to mm. trimesh keeps no colours or
materials of a 3MF, so these are read here: each triangle's property (its own ``pid`` /
``p1``, else its object's ``pid`` / ``pindex``) names a base material (name and display
colour) or a colour-group colour. Not yet wired into ``slice``.
"""

from __future__ import annotations

import io
import re
import xml.etree.ElementTree as ElementTree
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from heoslice.errors import InputError
from heoslice.files import open_regular
from heoslice.mesh.limits import MAX_TRIANGLES, MAX_TRIMESH_BYTES, MAX_VERTICES
from heoslice.mesh.raw import RawMesh

CORE = "{http://schemas.microsoft.com/3dmanufacturing/core/2015/02}"
MATERIAL = "{http://schemas.microsoft.com/3dmanufacturing/material/2015/02}"
_RELATIONSHIPS = "{http://schemas.openxmlformats.org/package/2006/relationships}"
_MODEL_TYPE = "http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel"

#: The model's unit attribute -> mm.
UNITS_MM = {"micron": 1e-3, "millimeter": 1.0, "centimeter": 10.0, "inch": 25.4, "foot": 304.8, "meter": 1000.0}
#: Deepest chain of components resolved (objects made of objects).
MAX_COMPONENT_DEPTH = 16


@dataclass(frozen=True)
class Material:
    """One material a 3MF names: its name and display colour (r, g, b, a) uint8.

    Base materials keep their names; colour-group colours are named 'colorgroup ID #INDEX'.
    """

    name: str
    color: tuple[int, int, int, int]


@dataclass(frozen=True)
class ModelObject:
    """One build item: its object's name, its geometry in mm, and each triangle's material.

    mesh: a :class:`RawMesh` with face_colors (the materials' display colours) where
    triangles have materials. face_material: (m,) int index into :attr:`ThreeMF.materials`,
    -1 for a triangle without one.
    """

    name: str
    object_id: str
    mesh: RawMesh
    face_material: np.ndarray


@dataclass(frozen=True)
class ThreeMF:
    """A 3MF file's build items (in build order) and every material they may refer to."""

    objects: tuple[ModelObject, ...]
    materials: tuple[Material, ...]


def read_3mf(path: str | Path) -> ThreeMF:
    """Read a 3MF file's build items and materials; any flaw is one InputError line naming the file."""
    path = Path(path)
    try:
        root = ElementTree.fromstring(_model_xml(path))
    except ElementTree.ParseError as err:
        raise InputError(f"{path}: 3MF model part is not well-formed XML (line {err.position[0]})") from None
    if root.tag != f"{CORE}model":
        raise InputError(f"{path}: 3MF model part has no <model> element in the 3MF core namespace")
    unit = root.get("unit", "millimeter")
    if unit not in UNITS_MM:
        raise InputError(f"{path}: 3MF unit {unit[:40]!r} is not one of {', '.join(UNITS_MM)}")
    resources = root.find(f"{CORE}resources")
    build = root.find(f"{CORE}build")
    if resources is None or build is None:
        raise InputError(f"{path}: 3MF model has no <resources> or no <build>")
    materials, groups = _materials(path, resources)
    objects = {element.get("id"): element for element in resources.findall(f"{CORE}object")}
    items = []
    budget = [MAX_VERTICES, MAX_TRIANGLES]
    for item in build.findall(f"{CORE}item"):
        object_id = item.get("objectid")
        if object_id not in objects:
            raise InputError(f"{path}: 3MF build item refers to object {str(object_id)[:20]!r}, which is not defined")
        parts = _placed(path, objects, object_id, _transform(path, item.get("transform")), groups, budget, 0)
        vertices = np.concatenate([p[0] for p in parts]) * UNITS_MM[unit]
        offsets = np.cumsum([0] + [len(p[0]) for p in parts[:-1]])
        faces = np.concatenate([p[1] + offset for p, offset in zip(parts, offsets)])
        face_material = np.concatenate([p[2] for p in parts])
        colored = face_material >= 0
        face_colors = None
        if colored.any():
            palette = np.array([m.color[:3] for m in materials] + [(255, 255, 255)], dtype=np.uint8)
            face_colors = palette[face_material]
        mesh = RawMesh(vertices, faces, face_colors=face_colors, color_source="face" if colored.any() else None)
        name = objects[object_id].get("name") or f"object {object_id}"
        items.append(ModelObject(name=name, object_id=object_id, mesh=mesh, face_material=face_material))
    if not items:
        raise InputError(f"{path}: 3MF build has no items")
    return ThreeMF(objects=tuple(items), materials=tuple(materials))


def _model_xml(path: Path) -> bytes:
    """The bytes of the 3MF model part, its declared and read size bounded; no DTD or entities accepted."""
    with open_regular(path, "3MF") as handle:
        data = handle.read()
    try:
        archive = zipfile.ZipFile(io.BytesIO(data))
    except zipfile.BadZipFile:
        raise InputError(f"{path}: not a 3MF file (not a zip archive)") from None
    with archive:
        name = _model_part(path, archive)
        try:
            info = archive.getinfo(name)
        except KeyError:
            raise InputError(f"{path}: 3MF has no model part {name!r}") from None
        if info.file_size > MAX_TRIMESH_BYTES:
            raise InputError(f"{path}: 3MF model part of {info.file_size} bytes is larger than the "
                             f"{MAX_TRIMESH_BYTES}-byte limit")
        try:
            with archive.open(info) as part:
                xml = part.read(MAX_TRIMESH_BYTES + 1)
        except (zipfile.BadZipFile, OSError, EOFError, NotImplementedError) as err:
            raise InputError(f"{path}: 3MF model part cannot be unpacked ({err})") from None
    if len(xml) > MAX_TRIMESH_BYTES:
        raise InputError(f"{path}: 3MF model part unpacks to more than {MAX_TRIMESH_BYTES} bytes")
    if re.search(rb"<!(?:DOCTYPE|ENTITY)", xml[:1 << 16]):
        raise InputError(f"{path}: 3MF model part declares a DTD or entities, which 3MF does not use")
    return xml


def _model_part(path: Path, archive: zipfile.ZipFile) -> str:
    """Name of the model part: the package relationship's target, else '3D/3dmodel.model'."""
    try:
        rels = ElementTree.fromstring(archive.read("_rels/.rels"))
    except (KeyError, ElementTree.ParseError):
        return "3D/3dmodel.model"
    for relation in rels.iter(f"{_RELATIONSHIPS}Relationship"):
        if relation.get("Type") == _MODEL_TYPE and relation.get("Target"):
            return relation.get("Target").lstrip("/")
    return "3D/3dmodel.model"


def _color(path: Path, text: str | None) -> tuple[int, int, int, int]:
    """'#RRGGBB' or '#RRGGBBAA' as (r, g, b, a) uint8 values."""
    if not text or not re.fullmatch(r"#[0-9A-Fa-f]{6}(?:[0-9A-Fa-f]{2})?", text):
        raise InputError(f"{path}: 3MF colour {str(text)[:20]!r} is not #RRGGBB or #RRGGBBAA")
    rgba = bytes.fromhex(text[1:] + ("FF" if len(text) == 7 else ""))
    return rgba[0], rgba[1], rgba[2], rgba[3]


def _materials(path: Path, resources) -> tuple[list[Material], dict[str, list[int]]]:
    """(every material, {property group id: material index of each of its entries}) of base materials and colour
    groups."""
    materials: list[Material] = []
    groups: dict[str, list[int]] = {}
    for group in resources.findall(f"{CORE}basematerials"):
        entries = group.findall(f"{CORE}base")
        groups[group.get("id")] = list(range(len(materials), len(materials) + len(entries)))
        materials += [Material(base.get("name") or f"material {group.get('id')} #{i}",
                               _color(path, base.get("displaycolor"))) for i, base in enumerate(entries)]
    for group in resources.findall(f"{MATERIAL}colorgroup"):
        entries = group.findall(f"{MATERIAL}color")
        groups[group.get("id")] = list(range(len(materials), len(materials) + len(entries)))
        materials += [Material(f"colorgroup {group.get('id')} #{i}", _color(path, color.get("color")))
                      for i, color in enumerate(entries)]
    return materials, groups


def _transform(path: Path, text: str | None) -> np.ndarray:
    """A 3MF transform (12 numbers, row vectors: p' = [x y z 1] M) as a (4, 3) float64 matrix; identity if absent."""
    if text is None:
        return np.vstack([np.eye(3), np.zeros((1, 3))])
    try:
        values = np.array([float(v) for v in text.split()], dtype=np.float64)
    except ValueError:
        values = np.zeros(0)
    if len(values) != 12 or not np.isfinite(values).all():
        raise InputError(f"{path}: 3MF transform {text[:60]!r} is not 12 finite numbers")
    return values.reshape(4, 3)


def _placed(path: Path, objects: dict, object_id: str, transform: np.ndarray, groups: dict[str, list[int]],
            budget: list[int], depth: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """[(vertices (n, 3) in the model's unit, faces (m, 3), face material (m,))] of an object under ``transform``."""
    if depth > MAX_COMPONENT_DEPTH:
        raise InputError(f"{path}: 3MF components nest deeper than {MAX_COMPONENT_DEPTH} (a cycle?)")
    element = objects[object_id]
    mesh = element.find(f"{CORE}mesh")
    if mesh is not None:
        vertices, faces, material = _object_mesh(path, object_id, element, mesh, groups, budget)
        return [(vertices @ transform[:3] + transform[3], faces, material)]
    components = element.find(f"{CORE}components")
    if components is None:
        raise InputError(f"{path}: 3MF object {object_id!r} has neither a mesh nor components")
    parts = []
    for component in components.findall(f"{CORE}component"):
        child = component.get("objectid")
        if child not in objects:
            raise InputError(f"{path}: 3MF component refers to object {str(child)[:20]!r}, which is not defined")
        local = _transform(path, component.get("transform"))
        combined = np.vstack([local[:3] @ transform[:3], local[3] @ transform[:3] + transform[3]])
        parts += _placed(path, objects, child, combined, groups, budget, depth + 1)
    if not parts:
        raise InputError(f"{path}: 3MF object {object_id!r} has no components")
    return parts


def _object_mesh(path: Path, object_id: str, element, mesh, groups: dict[str, list[int]],
                 budget: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertices (n, 3), faces (m, 3) int64, material index per face (m,), -1 for none) of one mesh object."""
    where = f"{path}: 3MF object {object_id!r}"
    vertex_elements = mesh.findall(f"{CORE}vertices/{CORE}vertex")
    triangle_elements = mesh.findall(f"{CORE}triangles/{CORE}triangle")
    budget[0] -= len(vertex_elements)
    budget[1] -= len(triangle_elements)
    if budget[0] < 0 or budget[1] < 0:
        raise InputError(f"{path}: 3MF build holds more than {MAX_VERTICES} vertices or {MAX_TRIANGLES} triangles")
    try:
        vertices = np.array([[float(v.get(axis)) for axis in "xyz"] for v in vertex_elements],
                            dtype=np.float64).reshape(-1, 3)
        faces = np.array([[int(t.get(k)) for k in ("v1", "v2", "v3")] for t in triangle_elements],
                         dtype=np.int64).reshape(-1, 3)
    except (TypeError, ValueError):
        raise InputError(f"{where}: a vertex or triangle has a missing or non-numeric attribute") from None
    if not np.isfinite(vertices).all():
        raise InputError(f"{where}: a vertex has a NaN or infinite coordinate")
    if len(faces) == 0:
        raise InputError(f"{where}: the mesh has no triangles")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise InputError(f"{where}: a triangle refers to a vertex outside 0..{len(vertices) - 1}")
    default_group, default_index = element.get("pid"), element.get("pindex", "0")
    material = np.full(len(faces), -1, dtype=np.int64)
    for row, triangle in enumerate(triangle_elements):
        group = triangle.get("pid", default_group)
        if group is None:
            continue
        index = triangle.get("p1", default_index if triangle.get("pid") is None else "0")
        entries = groups.get(group)
        if entries is None or not index.isdecimal() or int(index) >= len(entries):
            raise InputError(f"{where}: triangle {row} refers to property {group}:{index}, which is not defined")
        material[row] = entries[int(index)]
    return vertices, faces, material
