"""Materials: colour specs, the shared materials file, and the blend of eq. 1.

A material has a name, a display colour (what ``heoslice color`` writes into the PLY
and previews show) and a printer channel (the 1-based material channel of the
jetting head; channel 0 of a print job is the solid mask). ``color``, ``slice`` and
``print`` read the same TOML file::

    # materials.toml
    [materials.gel]
    color = "#f0f0f0"        # a colour name, #rgb / #rrggbb, "r,g,b" or [r, g, b]
    channel = 1

    [materials.cells]
    color = "0,255,0"
    channel = 2

    [shells]                 # optional: material of a connected shell, by shell number
    1 = "cells"

    [parts]                  # optional: material of a part of a multi-part job, by part name
    liver = "gel"            # (a file's stem, a 3MF object's name)
    lesion = { material = "cells", priority = 1 }   # higher priority wins where parts overlap

    [labels]                 # optional: material of a volume's label, by label value or segment name
    5 = "gel"                # (labels not listed are left out of the print)
    "tumour" = { material = "cells", priority = 1 }

Without a file the built-in default has two materials, ``M1`` (light grey
(240, 240, 240), channel 1) and ``M2`` (green (0, 255, 0), channel 2).

The default policy is one rule, :func:`material_roles`: M1 is the table's first
material and M2 its second, unless a start or target material is named; a colour named
on the command line that is a table material's colour is that material (its name and
channel).

Eq. 1 of the paper is misprinted (its middle case is f (M1 - M2) + M1, which leaves
M1..M2 the wrong way); :func:`blend` uses the corrected form M = M1 + f (M2 - M1)
with f clipped to [0, 1], so M = M1 where f <= 0 and M = M2 where f >= 1.
"""

from __future__ import annotations

import itertools
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from heoslice.errors import InputError
from heoslice.files import read_bounded

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib


@dataclass(frozen=True)
class Material:
    """A named material: display colour (r, g, b) 0..255 and 1-based printer channel (None = unassigned)."""

    name: str
    color: tuple[int, int, int]
    channel: int | None = None

    def record(self) -> dict:
        """The material as JSON records it (the manifest, ``--json``): name, [r, g, b], channel (or null)."""
        return {"name": self.name, "color": list(self.color), "channel": self.channel}


DEFAULT_MATERIALS = {
    "M1": Material("M1", (240, 240, 240), 1),
    "M2": Material("M2", (0, 255, 0), 2),
}
_TRIPLE = re.compile(r"^\s*\(?\s*([^,()]+),([^,()]+),([^,()]+)\)?\s*$")


#: The three ways of writing a colour, one colour each way (a CSS name's hex is CSS's: 'green' is #008000).
COLOUR_EXAMPLES = "a colour name such as 'red', a hex #ff0000 or r,g,b 255,0,0"


def parse_color(text) -> tuple[int, int, int]:
    """(r, g, b) 0..255 from a colour name ("green", CSS's #008000), "#0f0" / "#00ff00", or "0,255,0".

    Names and hex codes are Pillow's (CSS colour names). Raises InputError naming the text.
    """
    from PIL import ImageColor

    if isinstance(text, (list, tuple)) and len(text) == 3:
        text = ",".join(str(v) for v in text)
    spec = str(text).strip()
    match = _TRIPLE.match(spec)
    if match:
        parts = [part.strip() for part in match.groups()]
        if not all(re.fullmatch(r"\d{1,3}", part) for part in parts) or any(int(p) > 255 for p in parts):
            raise InputError(f"colour {spec!r}: r,g,b must be three whole numbers 0..255")
        return tuple(int(part) for part in parts)  # type: ignore[return-value]
    try:
        rgb = ImageColor.getrgb(spec)
    except (ValueError, AttributeError):
        raise InputError(f"colour {spec!r} does not parse (use {COLOUR_EXAMPLES})") from None
    return tuple(int(v) for v in rgb[:3])  # type: ignore[return-value]


def _material_from_table(name: str, entry, path: Path) -> Material:
    """One [materials.NAME] table of a materials file, checked."""
    if not isinstance(entry, dict):
        raise InputError(f"{path}: materials.{name} must be a table with 'color' (and 'channel')")
    unknown = set(entry) - {"color", "channel"}
    if unknown:
        raise InputError(f"{path}: materials.{name}: unknown key(s) {', '.join(sorted(unknown))} "
                         "(allowed: color, channel)")
    if "color" not in entry:
        raise InputError(f"{path}: materials.{name} has no 'color'")
    try:
        color = parse_color(entry["color"])
    except InputError as err:
        raise InputError(f"{path}: materials.{name}: {err}") from None
    channel = entry.get("channel")
    if channel is not None and not is_channel(channel):
        raise InputError(f"{path}: materials.{name}: channel must be a whole number from 1 to {MAX_CHANNEL}, "
                         f"got {channel!r}")
    return Material(name, color, channel)


#: Highest printer channel: a print job's channel count (the solid mask's channel 0 and one per printer
#: channel up to the highest a mask names) is one byte of JOB_BEGIN (docs/protocol.md).
MAX_CHANNEL = 254


def is_channel(value) -> bool:
    """A printer channel: a whole number from 1 to MAX_CHANNEL (JSON's true is not one); the rule of materials
    files and manifests."""
    return isinstance(value, int) and not isinstance(value, bool) and 1 <= value <= MAX_CHANNEL


#: A materials file is a few named colours; anything larger than this is not one (and is not read).
MAX_MATERIALS_FILE_BYTES = 1 << 20


def _read_toml(path: Path) -> dict:
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if path.is_dir():
        raise InputError(f"{path}: is a directory, not a materials file")
    try:
        return tomllib.loads(read_bounded(path, MAX_MATERIALS_FILE_BYTES, "materials").decode("utf-8"))
    except tomllib.TOMLDecodeError as err:
        raise InputError(f"{path}: not a valid TOML materials file ({err})") from None
    except RecursionError:
        raise InputError(f"{path}: arrays or tables nested too deeply; not a materials file") from None
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(f"{path}: cannot be read ({type(err).__name__}: {err})") from None


def _materials_of(data: dict, path: Path) -> dict[str, Material]:
    """{name: Material} of the [materials.NAME] tables of a parsed materials file, in file order."""
    table = data.get("materials")
    if not isinstance(table, dict) or not table:
        raise InputError(f"{path}: no [materials.NAME] tables (see heoslice color --help)")
    if len(table) > MAX_CHANNEL:
        raise InputError(f"{path}: {len(table)} materials, more than the printer's {MAX_CHANNEL} channels")
    return with_table_channels({str(name): _material_from_table(str(name), entry, path)
                                for name, entry in table.items()})


def with_table_channels(table: dict[str, Material]) -> dict[str, Material]:
    """The table with every material that names no printer channel given the lowest channel no material of
    the table names, in table order: a material's channel is the table's to say, never which of the table's
    materials a mesh happens to use (a stack holding some of them sends each to its own cartridge)."""
    taken = {material.channel for material in table.values() if material.channel is not None}
    free = (channel for channel in itertools.count(1) if channel not in taken)
    return {name: material if material.channel is not None else Material(material.name, material.color, next(free))
            for name, material in table.items()}


def _shells_of(data: dict, path: Path, table: dict[str, Material]) -> dict[int, Material]:
    """{shell number: Material} of the optional [shells] table of a parsed materials file ({} without one)."""
    shells = data.get("shells", {})
    if not isinstance(shells, dict):
        raise InputError(f"{path}: [shells] must map shell numbers to material names")
    out: dict[int, Material] = {}
    for key, value in shells.items():
        if not str(key).isdigit():
            raise InputError(f"{path}: [shells] key {key!r} is not a shell number (0, 1, 2...)")
        try:
            out[int(key)] = resolve_material(str(value), table)
        except InputError as err:
            raise InputError(f"{path}: [shells] {key}: {err}") from None
    return out


@dataclass(frozen=True)
class PartSetting:
    """What the materials file says of one part: its material's name, and its priority where parts overlap
    (None: the default rule, :func:`heoslice.pipeline.parts.part_order`)."""

    material: str
    priority: int | None = None


def _parts_of(data: dict, path: Path, table: dict[str, Material], section: str = "parts") -> dict[str, PartSetting]:
    """{part name: PartSetting} of the optional [parts] table of a parsed materials file ({} without one);
    ``section`` "labels" reads the [labels] table, of the same form, keyed by label value or name."""
    parts = data.get(section, {})
    if not isinstance(parts, dict):
        raise InputError(f"{path}: [{section}] must map {section[:-1]} names to material names")
    out = {}
    for name, value in parts.items():
        entry = {"material": value} if isinstance(value, str) else value
        if not isinstance(entry, dict) or not isinstance(entry.get("material"), str) or set(entry) - {"material",
                                                                                                      "priority"}:
            raise InputError(f"{path}: [{section}] {name}: give a material name, or "
                             "{ material = NAME, priority = N }")
        priority = entry.get("priority")
        if priority is not None and (isinstance(priority, bool) or not isinstance(priority, int)):
            raise InputError(f"{path}: [{section}] {name}: priority must be a whole number, got {priority!r}")
        if table_material(entry["material"], table) is None:
            raise InputError(f"{path}: [{section}] {name}: unknown material {entry['material']!r} "
                             f"(materials: {', '.join(table)})")
        out[str(name)] = PartSetting(entry["material"], priority)
    return out


@dataclass(frozen=True)
class MaterialsFile:
    """A materials file read once (:func:`read_materials_file`): its path (None: no file, the built-in
    default), its materials table in file order, and its parsed TOML, from which the optional [shells] and
    [parts] tables are checked when a command asks for them (so one read serves a whole command)."""

    path: Path | None
    materials: dict[str, Material]
    data: dict = field(default_factory=dict, repr=False)

    def shells(self) -> dict[int, Material]:
        """{shell number: Material} of the file's [shells] table ({} without one, or without a file)."""
        return {} if self.path is None else _shells_of(self.data, self.path, self.materials)

    def parts(self) -> dict[str, PartSetting]:
        """{part name: PartSetting} of the file's [parts] table ({} without one, or without a file); each
        material must be one of the file's materials."""
        return {} if self.path is None else _parts_of(self.data, self.path, self.materials)

    def labels(self) -> dict[str, PartSetting]:
        """{label value or segment name (as written): PartSetting} of the file's [labels] table ({} without
        one); each material must be one of the file's materials."""
        return {} if self.path is None else _parts_of(self.data, self.path, self.materials, "labels")

    @property
    def has_labels(self) -> bool:
        """Whether the file has a [labels] table (an empty one leaves every label out)."""
        return "labels" in self.data


def read_materials_file(path: Path | None) -> MaterialsFile:
    """The materials file at ``path``, read and its materials table checked (InputError naming the file),
    or the built-in two materials when ``path`` is None (nothing read)."""
    if path is None:
        return MaterialsFile(None, dict(DEFAULT_MATERIALS))
    data = _read_toml(Path(path))
    return MaterialsFile(Path(path), _materials_of(data, Path(path)), data)


def table_material(name: str, table: dict[str, Material]) -> Material | None:
    """The material of ``table`` named ``name`` (exactly, else ignoring case), or None."""
    if name in table:
        return table[name]
    folded = {key.lower(): material for key, material in table.items()}
    return folded.get(str(name).lower())


def resolve_material(text: str, table: dict[str, Material]) -> Material:
    """A material by name from ``table`` (exact, then case-insensitive), else a colour spec as an unnamed material."""
    spec = str(text).strip()
    if spec in table:
        return table[spec]
    folded = {name.lower(): material for name, material in table.items()}
    if spec.lower() in folded:
        return folded[spec.lower()]
    try:
        color = parse_color(spec)
    except InputError:
        raise InputError(f"{spec!r} is neither a material name ({', '.join(table) or 'none defined'}) "
                         f"nor a colour ({COLOUR_EXAMPLES})") from None
    return Material(spec, color, None)


def _table_material(material: Material | None, table: dict[str, Material]) -> Material | None:
    """An unnamed material (a colour given on the command line) that is a table material's colour is that material."""
    if material is None or material.channel is not None:
        return material
    return next((known for known in table.values() if known.color == material.color), material)


@dataclass(frozen=True)
class MaterialRoles:
    """Which material plays which part of eq. 1, by the one default rule of :func:`material_roles`.

    first, second: the table's first and second materials (second None for a one-material
    table), which a mesh's material fraction m mixes as (1 - m) first + m second; start,
    target: the materials named as M1 and M2, or None; ``table``: every table material, in order (the
    partner of a role named alone is taken from it).
    """

    first: Material
    second: Material | None
    start: Material | None
    target: Material | None
    table: tuple[Material, ...] = ()

    @property
    def m1(self) -> Material:
        """M1 (f <= 0): the named start material, else the table's first (its first other material when that one
        is the named target)."""
        if self.start is not None:
            return self.start
        return self._partner(self.first, self.target) or self.first

    @property
    def m2(self) -> Material | None:
        """M2 (f >= 1): the named target material, else the table's second (its first other material when that
        one is the named start; None for a one-material table)."""
        if self.target is not None:
            return self.target
        return self._partner(self.second, self.start)

    def _partner(self, default: Material | None, named: Material | None) -> Material | None:
        """``default`` unless it is the material named for the other role, then the table's first other one."""
        if default is None or named is None or not same_material(default, named):
            return default
        return next((m for m in self.table if not same_material(m, named)), None)


def material_identity(material: Material) -> tuple:
    """What makes two materials one (a role, a droplet mask): the same name and display colour."""
    return material.name, tuple(material.color)


def same_material(a: Material, b: Material) -> bool:
    """Whether two materials are one (:func:`material_identity`)."""
    return material_identity(a) == material_identity(b)


def material_roles(table: dict[str, Material], start: str | None = None,
                   target: str | None = None) -> MaterialRoles:
    """The roles of the materials of ``table`` with an optional start (M1) and target (M2) name or colour.

    Raises InputError naming the parameter (``start``, ``target``) that does not resolve, and naming both when
    they are one material (a grade from a material to itself jets it alone: nothing to design).
    """
    names = list(table)
    resolved = {}
    for parameter, text in (("start", start), ("target", target)):
        try:
            resolved[parameter] = _table_material(resolve_material(text, table), table) if text else None
        except InputError as err:
            raise InputError(f"{parameter}: {err}") from None
    if resolved["start"] is not None and resolved["target"] is not None and \
            same_material(resolved["start"], resolved["target"]):
        raise InputError(f"start, target: both name {resolved['start'].name!r}; a grade needs two materials")
    return MaterialRoles(first=table[names[0]], second=table[names[1]] if len(names) > 1 else None,
                         start=resolved["start"], target=resolved["target"], table=tuple(table.values()))


def blend(m1, m2, f: np.ndarray) -> np.ndarray:
    """Eq. 1, corrected: M1 + clip(f, 0, 1) (M2 - M1); (n, 3) float RGB for f (n,).

    m1, m2: (3,) colours (or Materials). M1 where f <= 0, M2 where f >= 1, linear between.
    """
    c1 = np.asarray(m1.color if isinstance(m1, Material) else m1, dtype=np.float64).reshape(1, -1)
    c2 = np.asarray(m2.color if isinstance(m2, Material) else m2, dtype=np.float64).reshape(1, -1)
    weight = np.clip(np.nan_to_num(np.asarray(f, dtype=np.float64).reshape(-1, 1), nan=0.0), 0.0, 1.0)
    return c1 + weight * (c2 - c1)


def shared_channel(named: list[tuple[str, int | None]]) -> tuple[int, list[str]] | None:
    """The lowest printer channel that two or more of ``named`` ((name, channel or None) pairs, the
    materials of one stack) name, with their names in order; None when each channel jets one material."""
    channels = [channel for _, channel in named if channel is not None]
    twice = sorted({channel for channel in channels if channels.count(channel) > 1})
    if not twice:
        return None
    return twice[0], [name for name, channel in named if channel == twice[0]]


def check_one_per_channel(materials: tuple[Material, ...] | list[Material], needing: str) -> None:
    """Refuse two of ``materials`` (distinct materials of one stack) that name the same printer channel
    (:func:`shared_channel`). ``needing`` says who needs it ("the parts", "the droplet masks")."""
    shared = shared_channel([(material.name, material.channel) for material in materials])
    if shared is not None:
        channel, names = shared
        both = "both" if len(names) == 2 else "all"
        raise InputError(f"materials: {', '.join(map(repr, names[:-1]))} and {names[-1]!r} {both} print on channel "
                         f"{channel}, but {needing} need one channel per material")


def nearest_materials(colors: np.ndarray, materials: tuple[Material, ...] | list[Material]) -> np.ndarray:
    """The material each colour stands for: (n,) int index into ``materials`` of the display colour nearest
    to it in RGB (ties to the first listed), so a colour that is a material's display colour is that
    material. colors: (n, 3) 0..255. The rule that maps a scan's or a part's colours to the materials table."""
    palette = np.array([m.color for m in materials], dtype=np.float64)
    rgb = np.asarray(colors, dtype=np.float64).reshape(-1, 3)
    if not len(palette):
        raise InputError("materials: no materials to map colours to")
    distance = ((rgb[:, None, :] - palette[None, :, :]) ** 2).sum(axis=-1)
    return np.argmin(distance, axis=1)


def to_rgb8(colors: np.ndarray) -> np.ndarray:
    """(n, 3) float colours 0..255 rounded to (n, 3) uint8."""
    return np.clip(np.rint(colors), 0, 255).astype(np.uint8)
