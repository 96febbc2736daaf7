"""The design a coloured model carries: what ``heoslice color`` did, recorded in the PLY for ``slice`` (issue 44).

``color`` writes, and ``slice`` reads, one :class:`Design` per model as PLY header comment lines, one per
field, each ``heoslice design <version> <field> <JSON>`` (the JSON without spaces: a space inside a string is
written ``\\u0020``, so the header's one-space-per-gap rule keeps it byte for byte)::

    comment heoslice design 1 start {"name":"M1","color":[240,240,240],"channel":1}
    comment heoslice design 1 target {"name":"255,0,0","color":[255,0,0],"channel":null}
    comment heoslice design 1 reference {"kind":"plane","point":[0.0,0.0,0.0],"direction":[0.0,0.0,1.0]}
    comment heoslice design 1 function {"kind":"linear","alpha":1.0,"beta":0.0,"lam":0.0,"expression":null}
    comment heoslice design 1 range {"mm":[0.0,60.0],"from":"max"}
    comment heoslice design 1 shell {"number":1,"material":{"name":"tumour","color":[255,0,0],"channel":3}}

- ``start``, ``target``: M1 (f <= 0) and M2 (f >= 1) of eq. 1, by name, display colour and printer channel
  (null: a colour given on the command line, no channel); the vertex property ``material`` is the share of
  ``target``.
- ``reference``: the resolved reference feature (kind ``plane``/``point``/``axis`` with its point and unit
  direction, mm; ``surface`` with the reference mesh's absolute ``path`` and the ``sha256`` of its bytes).
- ``function``: the distribution function f(r) (kind and coefficients, or the expression).
- ``range``: the distances (mm) mapped to r = 0 and r = 1 (``from`` ``"range"``: given by ``--range``;
  ``"max"``: 0 and the largest vertex distance), r = clip((d - R0) / (R1 - R0), 0, 1).
- ``shell`` (any number): a shell coloured whole with a material.

A reader refuses a version it does not know. The version is :data:`DESIGN_VERSION`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

from heoslice.errors import InputError, MalformedDesign
from heoslice.material.functions import DistributionFunction, make_function
from heoslice.material.materials import Material, table_material

#: The interiors a coloured model's solid can get (``slice --interior``): the design's f(r) at every voxel in 3D
#: (:mod:`heoslice.material.field`), or the contour's material carried inward (the paper's layer-wise Z-axis
#: distribution); ``graded`` is ``--grade``'s eq. 8-10 sub-regions.
INTERIORS = ("field", "contour", "graded")
#: The version of the design record this heoslice writes and reads.
DESIGN_VERSION = 1
#: What every design comment line starts with.
DESIGN_PREFIX = "heoslice design"
_FIELDS = ("start", "target", "reference", "function", "range")


@dataclass(frozen=True)
class ReferenceRecord:
    """A resolved reference feature as recorded: kind, point and unit direction ((3,) mm; None where the kind
    has none) and, for a surface, the reference mesh's absolute path and the SHA-256 of its bytes."""

    kind: str
    point: tuple[float, float, float] | None = None
    direction: tuple[float, float, float] | None = None
    surface: str | None = None
    surface_sha256: str | None = None
    #: How much the reference surface file's coordinates are to be multiplied by (``color --scale`` times ``slice
    #: --scale``), recorded as ``scale`` (a record without it is older: its surface at the slice's --scale alone).
    surface_scale: float = 1.0

    def record(self) -> dict:
        out = {"kind": self.kind}
        if self.kind == "surface":
            out.update(path=self.surface, sha256=self.surface_sha256, scale=self.surface_scale)
        else:
            out["point"] = None if self.point is None else list(self.point)
            if self.direction is not None:
                out["direction"] = list(self.direction)
        return out


@dataclass(frozen=True)
class Design:
    """What a coloured model was designed as (the module's record): M1 ``start`` and M2 ``target``, the
    reference, f(r), the distances ``r_range`` (R0, R1) mm mapped to r = 0 and 1 (``range_from`` 'range' or
    'max') and the shells coloured whole ((number, Material) pairs)."""

    start: Material
    target: Material
    reference: ReferenceRecord
    function: DistributionFunction
    r_range: tuple[float, float]
    range_from: str = "max"
    shells: tuple[tuple[int, Material], ...] = ()

    def record(self) -> dict:
        """The design as JSON (the manifest's ``grading.design``)."""
        function = self.function
        return {"version": DESIGN_VERSION, "start": self.start.record(), "target": self.target.record(),
                "reference": self.reference.record(),
                "function": {"kind": function.kind, "alpha": function.alpha, "beta": function.beta,
                             "lam": function.lam, "expression": function.expression,
                             "written": function.describe()},
                "range": {"mm": list(self.r_range), "from": self.range_from},
                "shells": [{"number": n, "material": m.record()} for n, m in self.shells]}

    def to_header(self) -> tuple[str, ...]:
        """The PLY header comment lines (without the word ``comment``) that record this design."""
        full = self.record()
        fields = {"start": full["start"], "target": full["target"], "reference": full["reference"],
                  "function": {k: v for k, v in full["function"].items() if k != "written"},
                  "range": full["range"]}
        lines = [_line(name, value) for name, value in fields.items()]
        lines += [_line("shell", shell) for shell in full["shells"]]
        return tuple(lines)

    @classmethod
    def from_header(cls, comments, source: str = "model") -> Design | None:
        """The design recorded in a PLY's header comment lines (``comments``, each without ``comment``), or None
        when there is none. InputError naming ``source`` for an unknown version or a malformed record."""
        fields: dict = {}
        shells = []
        for line in comments:
            words = str(line).split(" ", 4)
            if " ".join(words[:2]) != DESIGN_PREFIX:
                continue
            if len(words) != 5:
                raise InputError(f"{source}: malformed design line {line[:80]!r}")
            version, name, text = words[2], words[3], words[4]
            if version != str(DESIGN_VERSION):
                raise InputError(f"{source}: design record version {version} (this heoslice reads version "
                                 f"{DESIGN_VERSION}); colour the model again with this heoslice")
            try:
                value = json.loads(text)
            except json.JSONDecodeError:
                raise InputError(f"{source}: design field {name!r} is not valid JSON") from None
            if name == "shell":
                shells.append(value)
            else:
                fields[name] = value
        if not fields and not shells:
            return None
        missing = [name for name in _FIELDS if name not in fields]
        if missing:
            raise InputError(f"{source}: design record lacks {', '.join(missing)}")
        try:
            return _design_of(fields, shells)
        except (KeyError, TypeError, ValueError, IndexError) as err:
            raise InputError(f"{source}: malformed design record ({type(err).__name__}: {err})") from None

    @classmethod
    def from_record(cls, record: dict, source: str = "stack") -> Design:
        """The design a stack's manifest records (``grading.design``, :meth:`record`). InputError naming
        ``source`` for an unknown version or a malformed record."""
        version = record.get("version") if isinstance(record, dict) else None
        if version != DESIGN_VERSION:
            raise MalformedDesign(f"{source}: design record version {version} (this heoslice reads version "
                             f"{DESIGN_VERSION})")
        try:
            return _design_of(record, list(record.get("shells") or []))
        except InputError as err:  # a function the record names that heoslice does not make
            raise MalformedDesign(f"{source}: malformed design record ({err})") from None
        except (KeyError, TypeError, ValueError, IndexError) as err:
            raise MalformedDesign(f"{source}: malformed design record ({type(err).__name__}: {err})") from None

    def scaled(self, factor: float) -> Design:
        """The design of the model with coordinates multiplied by ``factor`` (``slice --scale``): the reference
        point and the range in mm scale with it (r, f and the materials do not change)."""
        if factor == 1.0:
            return self
        point = self.reference.point
        reference = replace(self.reference, point=None if point is None else tuple(factor * v for v in point),
                            surface_scale=self.reference.surface_scale * factor)
        return replace(self, reference=reference, r_range=(self.r_range[0] * factor, self.r_range[1] * factor))

    def materials(self) -> tuple[Material, ...]:
        """Every material the design names: start, target, then the shells', in that order."""
        return (self.start, self.target, *(m for _, m in self.shells))


def design_of(mesh) -> Design | None:
    """The design a loaded mesh's header records (:meth:`Design.from_header`), or None."""
    return Design.from_header(getattr(mesh, "comments", ()), str(getattr(mesh, "source", "model")))


def _line(name: str, value) -> str:
    text = json.dumps(value, separators=(",", ":"), ensure_ascii=True, allow_nan=False).replace(" ", "\\u0020")
    return f"{DESIGN_PREFIX} {DESIGN_VERSION} {name} {text}"


def _material(value: dict) -> Material:
    channel = value["channel"]
    color = tuple(int(c) for c in value["color"])
    if len(color) != 3 or not all(0 <= c <= 255 for c in color):
        raise ValueError(f"colour {value['color']!r}")
    return Material(str(value["name"]), color, None if channel is None else int(channel))  # type: ignore[arg-type]


def _scale(value) -> float:
    scale = float(value)
    if not (math.isfinite(scale) and scale > 0):
        raise ValueError(f"scale {value!r}")
    return scale


def _vector(value) -> tuple[float, float, float] | None:
    if value is None:
        return None
    vector = tuple(float(v) for v in value)
    if len(vector) != 3:
        raise ValueError(f"vector {value!r}")
    return vector  # type: ignore[return-value]


def _design_of(fields: dict, shells: list) -> Design:
    from heoslice.material.functions import FUNCTION_KINDS
    from heoslice.material.references import REFERENCES

    ref = fields["reference"]
    reference = ReferenceRecord(str(ref["kind"]), _vector(ref.get("point")), _vector(ref.get("direction")),
                                ref.get("path"), ref.get("sha256"), _scale(ref.get("scale", 1.0)))
    kind = REFERENCES.get(reference.kind)
    if kind is None:
        raise ValueError(f"reference kind {reference.kind!r}")
    if kind.closed_form is not None and reference.point is None:
        raise ValueError(f"a {reference.kind} reference without its point")
    if {"normal", "direction"} & set(kind.options) and reference.direction is None:
        raise ValueError(f"a {reference.kind} reference without its direction")
    fn = fields["function"]
    if fn["kind"] == "expression":
        function = make_function("expression", expression=fn["expression"])
    elif fn["kind"] not in FUNCTION_KINDS:
        raise ValueError(f"function kind {fn['kind']!r}")
    else:
        function = DistributionFunction(str(fn["kind"]), float(fn["alpha"]), float(fn["beta"]), float(fn["lam"]))
    low, high = (float(v) for v in fields["range"]["mm"])
    if not high > low:
        raise ValueError(f"range {low:g} {high:g} mm")
    return Design(_material(fields["start"]), _material(fields["target"]), reference, function, (low, high),
                  str(fields["range"].get("from", "max")),
                  tuple((int(s["number"]), _material(s["material"])) for s in shells))


def _shown(material: Material) -> str:
    channel = "no channel" if material.channel is None else f"channel {material.channel}"
    return f"{material.name!r} ({','.join(map(str, material.color))}, {channel})"


def settle_materials(design: Design, table: dict[str, Material] | None, table_name: str,
                     source: str = "model") -> Design:
    """The design with its materials as the slice's materials table has them: the one rule by which a design
    meets ``--materials``.

    Without a table (None: no materials file) the design's own materials are the stack's, as recorded. With
    one, a recorded material is the table's material of the same name, which must have the recorded display
    colour and (if one was recorded) channel; a recorded colour without a channel (``color --to 255,0,0``) is
    the table material of that colour. Anything else is an InputError naming both the model's material and
    ``table_name``.
    """
    if table is None:
        return design

    def settled(role: str, material: Material) -> Material:
        return settle_material(material, table, role, table_name, source)

    return replace(design, start=settled("start", design.start), target=settled("target", design.target),
                   shells=tuple((n, settled(f"shell {n}", m)) for n, m in design.shells))


def settle_material(material: Material, table: dict[str, Material], role: str, table_name: str,
                    source: str = "model") -> Material:
    """One material of a design as ``table`` has it (:func:`settle_materials`' rule): the table's material of the
    same name, with the same colour and (if given) channel, else, for a colour without a channel, the table's
    material of that colour; InputError naming ``source``, the ``role`` and ``table_name`` otherwise."""
    known = table_material(material.name, table)
    if known is None and material.channel is None:
        known = next((m for m in table.values() if m.color == material.color), None)
    if known is None:
        raise InputError(f"{source}: the design's {role} material {_shown(material)} is not in {table_name} "
                         f"(materials: {', '.join(table)})")
    if known.color != material.color or (material.channel is not None and known.channel != material.channel):
        raise InputError(f"{source}: the design's {role} material is {_shown(material)}, but {table_name} "
                         f"has {_shown(known)}")
    return known


def surface_path(design: Design, model: Path | None) -> Path:
    """Where the design's reference surface is read from: its recorded absolute path, else a file of the same
    name beside the model (a model and its reference moved together). InputError when neither exists."""
    recorded = Path(str(design.reference.surface))
    if recorded.is_file():
        return recorded
    beside = None if model is None else Path(model).parent / recorded.name
    if beside is not None and beside.is_file():
        return beside
    elsewhere = "" if beside is None else f" (nor is {recorded.name} in {beside.parent})"
    raise InputError(f"{model or 'model'}: the design's reference surface {recorded} is missing{elsewhere}")
