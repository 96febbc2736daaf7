"""3MF reading: objects with their names, base materials and colour groups, read by heoslice itself.

A 3MF file is a zip archive whose model part (``3D/3dmodel.model``, or the part named by
the package relationships) is XML in the 3MF core namespace. Geometry is placed as
trimesh places it: every build item is its object (components resolved) under the
item's transform, in the model's unit converted to mm. trimesh keeps no colours or
materials of a 3MF, so these are read here: each triangle's property (its own ``pid`` /
``p1``, else its object's ``pid`` / ``pindex``) names a base material (name and display
colour) or a colour-group colour.

Within the resource model of the other readers (:mod:`heoslice.mesh.limits`): every zip member is
checked (declared size, encryption, compression method, CRC) and read to at most its limit, so
a zip bomb unpacks no further; the model XML is parsed as a stream (vertices and triangles go
into flat arrays as they arrive, their elements dropped), within the mesh budget; and the
placements of the build (items times nested components) are counted, and bounded, before
any is expanded. Every flaw is one InputError line naming the file.
"""

from __future__ import annotations

import io
import re
import xml.etree.ElementTree as ElementTree
import zipfile
from array import array
from dataclasses import dataclass, field
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
#: Most placed meshes of a build (items times the components they nest), counted before any is expanded.
MAX_PLACEMENTS = 100_000
#: Most bytes read of the package relationships part.
MAX_RELS_BYTES = 1 << 20
#: Bytes of the model part fed to the XML parser at a time.
_CHUNK = 1 << 16
_ZIP_METHODS = {zipfile.ZIP_STORED: "stored", zipfile.ZIP_DEFLATED: "deflate"}


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
    with open_regular(path, "3MF") as handle:
        data = handle.read()
    try:
        archive = zipfile.ZipFile(io.BytesIO(data))
    except (zipfile.BadZipFile, zipfile.LargeZipFile, ValueError, EOFError, OSError):
        raise InputError(f"{path}: not a 3MF file (not a zip archive)") from None
    with archive:
        model = _Model(path)
        _parse(path, archive, _model_part(path, archive), model)
    return model.assemble()


def _member(path: Path, archive: zipfile.ZipFile, name: str, limit: int):
    """The open stream of member ``name`` after checking its header: not encrypted, a known compression, a
    declared size within ``limit``; None when the archive has no such member."""
    try:
        info = archive.getinfo(name)
    except KeyError:
        return None
    if info.flag_bits & 0x1:
        raise InputError(f"{path}: 3MF part {name!r} is encrypted")
    if info.compress_type not in _ZIP_METHODS:
        raise InputError(f"{path}: 3MF part {name!r} uses compression method {info.compress_type}, not "
                         f"{' or '.join(_ZIP_METHODS.values())}")
    if info.file_size > limit:
        raise InputError(f"{path}: 3MF part {name!r} declares {info.file_size} bytes, more than the {limit}-byte limit")
    try:
        return archive.open(info)
    except (zipfile.BadZipFile, OSError, EOFError, NotImplementedError, RuntimeError, ValueError) as err:
        raise InputError(f"{path}: 3MF part {name!r} cannot be unpacked ({_said(err)})") from None


def _said(err: BaseException) -> str:
    """An unpacking error in a few words ('Bad CRC-32 for file ...' reads as a bad CRC)."""
    text = " ".join(str(err).split())[:80] or type(err).__name__
    return "bad CRC-32: the part is damaged" if "CRC" in text else text


def _chunks(path: Path, name: str, stream, limit: int):
    """The bytes of a member stream in chunks, at most ``limit`` in all whatever its header declared (a zip
    bomb stops here); unpacking errors and a bad CRC become one InputError line."""
    total = 0
    try:
        while True:
            chunk = stream.read(_CHUNK)
            if not chunk:
                return
            total += len(chunk)
            if total > limit:
                raise InputError(f"{path}: 3MF part {name!r} unpacks to more than {limit} bytes")
            yield chunk
    except (zipfile.BadZipFile, OSError, EOFError, NotImplementedError, RuntimeError, ValueError) as err:
        raise InputError(f"{path}: 3MF part {name!r} cannot be unpacked ({_said(err)})") from None


def _model_part(path: Path, archive: zipfile.ZipFile) -> str:
    """Name of the model part: the package relationship's target, else '3D/3dmodel.model'."""
    stream = _member(path, archive, "_rels/.rels", MAX_RELS_BYTES)
    if stream is None:
        return "3D/3dmodel.model"
    with stream:
        data = b"".join(_chunks(path, "_rels/.rels", stream, MAX_RELS_BYTES))
    _refuse_dtd(path, data)
    try:
        rels = ElementTree.fromstring(data)
    except ElementTree.ParseError:
        return "3D/3dmodel.model"
    for relation in rels.iter(f"{_RELATIONSHIPS}Relationship"):
        if relation.get("Type") == _MODEL_TYPE and relation.get("Target"):
            return relation.get("Target").lstrip("/")
    return "3D/3dmodel.model"


def _refuse_dtd(path: Path, data: bytes) -> None:
    if re.search(rb"<!(?:DOCTYPE|ENTITY)", data):
        raise InputError(f"{path}: 3MF model part declares a DTD or entities, which 3MF does not use")


def _parse(path: Path, archive: zipfile.ZipFile, name: str, model: "_Model") -> None:
    """Stream the model part through the XML parser into ``model``; elements are dropped once read."""
    stream = _member(path, archive, name, MAX_TRIMESH_BYTES)
    if stream is None:
        raise InputError(f"{path}: 3MF has no model part {name!r}")
    parser = ElementTree.XMLPullParser(events=("start", "end"))
    tail = b""
    try:
        with stream:
            for chunk in _chunks(path, name, stream, MAX_TRIMESH_BYTES):
                _refuse_dtd(path, tail + chunk)
                tail = chunk[-16:]
                parser.feed(chunk)
                for event, element in parser.read_events():
                    model.take(event, element)
            parser.close()
            for event, element in parser.read_events():
                model.take(event, element)
    except ElementTree.ParseError as err:
        raise InputError(f"{path}: 3MF model part is not well-formed XML (line {err.position[0]})") from None


@dataclass
class _Object:
    """An object of the resources as read: its mesh as flat arrays, or its components."""

    object_id: str
    name: str | None
    vertices: array = field(default_factory=lambda: array("d"))
    triangles: array = field(default_factory=lambda: array("q"))
    material: array = field(default_factory=lambda: array("q"))
    components: list = field(default_factory=list)
    has_mesh: bool = False


class _Model:
    """The state of one streamed model part (a parser's state, so a class): materials, objects, build items."""

    def __init__(self, path: Path):
        self.path = path
        self.unit = "millimeter"
        self.materials: list[Material] = []
        self.groups: dict[str, list[int]] = {}
        self.objects: dict[str, _Object] = {}
        self.items: list[tuple[str, np.ndarray]] = []
        self.vertex_count = self.triangle_count = 0
        self._object: _Object | None = None
        self._group: tuple[str, list[int], str] | None = None
        self._container = None
        self._default: tuple[str | None, str] = (None, "0")
        self._sections: set[str] = set()
        self._root_seen = False

    def take(self, event: str, element) -> None:
        """One parser event: read what the element says and drop what is done with."""
        tag = element.tag
        if event == "start":
            self._start(tag, element)
            return
        if tag == f"{CORE}vertex":
            self._vertex(element)
            self._container.clear()
        elif tag == f"{CORE}triangle":
            self._triangle(element)
            self._container.clear()
        elif tag in (f"{CORE}base", f"{MATERIAL}color"):
            self._entry(element)
        elif tag == f"{CORE}component":
            self._component(element)
        elif tag == f"{CORE}item":
            self._item(element)
        elif tag == f"{CORE}object":
            self._end_object()
            element.clear()
        elif tag in (f"{CORE}basematerials", f"{MATERIAL}colorgroup"):
            self._group = None
            element.clear()

    def _start(self, tag: str, element) -> None:
        if not self._root_seen:
            self._root_seen = True
            if tag != f"{CORE}model":
                raise InputError(f"{self.path}: 3MF model part has no <model> element in the 3MF core namespace")
            self.unit = element.get("unit", "millimeter")
            if self.unit not in UNITS_MM:
                raise InputError(f"{self.path}: 3MF unit {self.unit[:40]!r} is not one of {', '.join(UNITS_MM)}")
        elif tag in (f"{CORE}resources", f"{CORE}build"):
            self._sections.add(tag)
        elif tag == f"{CORE}object":
            object_id = element.get("id")
            self._object = _Object(object_id, element.get("name"))
            self._default = (element.get("pid"), element.get("pindex", "0"))
        elif tag == f"{CORE}mesh" and self._object is not None:
            self._object.has_mesh = True
        elif tag in (f"{CORE}vertices", f"{CORE}triangles"):
            self._container = element
        elif tag in (f"{CORE}basematerials", f"{MATERIAL}colorgroup"):
            group_id = element.get("id")
            self._group = (group_id, [], "base" if tag == f"{CORE}basematerials" else "color")
            self.groups[group_id] = self._group[1]

    def _vertex(self, element) -> None:
        self.vertex_count += 1
        if self.vertex_count > MAX_VERTICES:
            raise InputError(f"{self.path}: 3MF build holds more than {MAX_VERTICES} vertices or {MAX_TRIANGLES} "
                             "triangles")
        try:
            self._object.vertices.extend(float(element.get(axis)) for axis in "xyz")
        except (TypeError, ValueError, AttributeError):
            raise InputError(f"{self._where()}: a vertex or triangle has a missing or non-numeric attribute") from None

    def _triangle(self, element) -> None:
        self.triangle_count += 1
        if self.triangle_count > MAX_TRIANGLES:
            raise InputError(f"{self.path}: 3MF build holds more than {MAX_VERTICES} vertices or {MAX_TRIANGLES} "
                             "triangles")
        obj = self._object
        try:
            obj.triangles.extend(int(element.get(k)) for k in ("v1", "v2", "v3"))
        except (TypeError, ValueError, AttributeError, OverflowError):
            raise InputError(f"{self._where()}: a vertex or triangle has a missing or non-numeric attribute") from None
        group = element.get("pid", self._default[0])
        if group is None:
            obj.material.append(-1)
            return
        index = element.get("p1", self._default[1] if element.get("pid") is None else "0")
        entries = self.groups.get(group)
        if entries is None or not index.isdecimal() or int(index) >= len(entries):
            raise InputError(f"{self._where()}: triangle {len(obj.material)} refers to property {group}:{index}, "
                             "which is not defined")
        obj.material.append(entries[int(index)])

    def _entry(self, element) -> None:
        if self._group is None:
            return
        group_id, entries, kind = self._group
        entries.append(len(self.materials))
        if kind == "base":
            name = element.get("name") or f"material {group_id} #{len(entries) - 1}"
            color = _color(self.path, element.get("displaycolor"))
        else:
            name, color = f"colorgroup {group_id} #{len(entries) - 1}", _color(self.path, element.get("color"))
        self.materials.append(Material(name, color))
        element.clear()

    def _component(self, element) -> None:
        if self._object is not None:
            self._object.components.append((element.get("objectid"), _transform(self.path, element.get("transform"))))
            if len(self._object.components) > MAX_PLACEMENTS:
                raise InputError(f"{self._where()}: more than {MAX_PLACEMENTS} components")
        element.clear()

    def _item(self, element) -> None:
        self.items.append((element.get("objectid"), _transform(self.path, element.get("transform"))))
        if len(self.items) > MAX_PLACEMENTS:
            raise InputError(f"{self.path}: 3MF build has more than {MAX_PLACEMENTS} items")
        element.clear()

    def _end_object(self) -> None:
        obj = self._object
        if obj is not None:
            self.objects[obj.object_id] = obj
        self._object = None

    def _where(self) -> str:
        return f"{self.path}: 3MF object {self._object.object_id if self._object else None!r}"

    # -- after the whole part is read ------------------------------------------------------

    def assemble(self) -> ThreeMF:
        """The build items, each its objects placed: placements counted and bounded before any is expanded."""
        path = self.path
        if not self._root_seen:
            raise InputError(f"{path}: 3MF model part has no <model> element in the 3MF core namespace")
        if {f"{CORE}resources", f"{CORE}build"} - self._sections:
            raise InputError(f"{path}: 3MF model has no <resources> or no <build>")
        for object_id, _ in self.items:
            if object_id not in self.objects:
                raise InputError(f"{path}: 3MF build item refers to object {str(object_id)[:20]!r}, which is not "
                                 "defined")
        sizes: dict[str, tuple[int, int]] = {}
        placements = triangles = 0
        for object_id, _ in self.items:
            count, faces = self._size(object_id, sizes, 0)
            placements, triangles = placements + count, triangles + faces
            if placements > MAX_PLACEMENTS or triangles > MAX_TRIANGLES:
                raise InputError(f"{path}: 3MF build places {placements} meshes of {triangles} triangles (items times "
                                 f"nested components), more than {MAX_PLACEMENTS} meshes or {MAX_TRIANGLES} triangles")
        items = [self._item_object(object_id, transform) for object_id, transform in self.items]
        if not items:
            raise InputError(f"{path}: 3MF build has no items")
        return ThreeMF(objects=tuple(items), materials=tuple(self.materials))

    def _size(self, object_id: str, sizes: dict, depth: int) -> tuple[int, int]:
        """(meshes placed, triangles placed) by one use of ``object_id``, memoised, in exact integers."""
        if depth > MAX_COMPONENT_DEPTH:
            raise InputError(f"{self.path}: 3MF components nest deeper than {MAX_COMPONENT_DEPTH} (a cycle?)")
        if object_id in sizes:
            return sizes[object_id]
        obj = self.objects.get(object_id)
        if obj is None:
            raise InputError(f"{self.path}: 3MF component refers to object {str(object_id)[:20]!r}, which is not "
                             "defined")
        if obj.has_mesh:
            size = (1, len(obj.triangles) // 3)
        elif obj.components:
            size = (0, 0)
            for child, _ in obj.components:
                count, faces = self._size(child, sizes, depth + 1)
                size = (size[0] + count, size[1] + faces)
        else:
            raise InputError(f"{self.path}: 3MF object {object_id!r} has neither a mesh nor components")
        sizes[object_id] = size
        return size

    def _item_object(self, object_id: str, transform: np.ndarray) -> ModelObject:
        parts = self._placed(object_id, transform)
        vertices = np.concatenate([p[0] for p in parts]) * UNITS_MM[self.unit]
        offsets = np.cumsum([0] + [len(p[0]) for p in parts[:-1]])
        faces = np.concatenate([p[1] + offset for p, offset in zip(parts, offsets)])
        face_material = np.concatenate([p[2] for p in parts])
        colored = face_material >= 0
        face_colors = None
        if colored.any():
            palette = np.array([m.color[:3] for m in self.materials] + [(255, 255, 255)], dtype=np.uint8)
            face_colors = palette[face_material]
        mesh = RawMesh(vertices, faces, face_colors=face_colors, color_source="face" if colored.any() else None)
        name = self.objects[object_id].name or f"object {object_id}"
        return ModelObject(name=name, object_id=object_id, mesh=mesh, face_material=face_material)

    def _placed(self, object_id: str, transform: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """[(vertices (n, 3) in the model's unit, faces (m, 3), face material (m,))] of an object under ``transform``
        (sizes already bounded by :meth:`_size`)."""
        obj = self.objects[object_id]
        if obj.has_mesh:
            vertices, faces, material = self._mesh(obj)
            return [(vertices @ transform[:3] + transform[3], faces, material)]
        parts = []
        for child, local in obj.components:
            combined = np.vstack([local[:3] @ transform[:3], local[3] @ transform[:3] + transform[3]])
            parts += self._placed(child, combined)
        return parts

    def _mesh(self, obj: _Object) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(vertices (n, 3), faces (m, 3) int64, material index per face (m,)) of one mesh object, checked."""
        where = f"{self.path}: 3MF object {obj.object_id!r}"
        vertices = np.frombuffer(obj.vertices, dtype=np.float64).reshape(-1, 3)
        faces = np.frombuffer(obj.triangles, dtype=np.int64).reshape(-1, 3)
        if not np.isfinite(vertices).all():
            raise InputError(f"{where}: a vertex has a NaN or infinite coordinate")
        if len(faces) == 0:
            raise InputError(f"{where}: the mesh has no triangles")
        if faces.min() < 0 or faces.max() >= len(vertices):
            raise InputError(f"{where}: a triangle refers to a vertex outside 0..{len(vertices) - 1}")
        return vertices, faces, np.frombuffer(obj.material, dtype=np.int64)


def _color(path: Path, text: str | None) -> tuple[int, int, int, int]:
    """'#RRGGBB' or '#RRGGBBAA' as (r, g, b, a) uint8 values."""
    if not text or not re.fullmatch(r"#[0-9A-Fa-f]{6}(?:[0-9A-Fa-f]{2})?", text):
        raise InputError(f"{path}: 3MF colour {str(text)[:20]!r} is not #RRGGBB or #RRGGBBAA")
    rgba = bytes.fromhex(text[1:] + ("FF" if len(text) == 7 else ""))
    return rgba[0], rgba[1], rgba[2], rgba[3]


def _transform(path: Path, text: str | None) -> np.ndarray:
    """A 3MF transform (12 numbers, row vectors: p' = [x y z 1] M) as a (4, 3) float64 matrix; identity if absent."""
    if text is None:
        return np.vstack([np.eye(3), np.zeros((1, 3))])
    try:
        values = np.array([float(v) for v in text.split()[:13]], dtype=np.float64)
    except ValueError:
        values = np.zeros(0)
    if len(values) != 12 or not np.isfinite(values).all():
        raise InputError(f"{path}: 3MF transform {text[:60]!r} is not 12 finite numbers")
    return values.reshape(4, 3)
