"""Multi-part jobs: several parts (mesh files, a 3MF's objects) sliced into one stack, each part's pixels
carrying its part's material.

The parts are sliced in one pass as one assembly (:func:`heoslice.mesh.load_assembly`: every
face knows its part, so every contour loop does through ``Contours.face``). Each layer's loops
are rasterised part by part (:func:`heoslice.layers.rasterising.packed_mask`) and the packed
part masks are composed by priority with bitwise operations on the packed bytes
(:func:`compose_part_masks`): the solid mask is their union, and a pixel inside several parts
belongs to the one that ranks first (:func:`part_order`): the higher ``priority`` given in the
materials file, else (the default, priority 0) the part of smaller volume, as an enclosed part
(a lesion in its organ) always is; equal ranks go to the part listed first. A stack with more
than one material has one 1-bit droplet mask per material per layer, like ``slice --channels``.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from heoslice.errors import InputError
from heoslice.layers.bits import count_solid
from heoslice.layers.rasterising import Grid, packed_mask
from heoslice.material import Material, PartSetting, check_one_per_channel, nearest_materials, table_material
from heoslice.pipeline.spec import channel_name
from heoslice.stack import encode_bilevel_tiff, layer_file_name, write_file
from heoslice.stack.tiff import deflate_level, mask_deflation

if TYPE_CHECKING:
    from heoslice.layers.contours import Contours
    from heoslice.mesh import Part
    from heoslice.pipeline.runs import RunContext

#: Most droplet masks a layer can carry: the print protocol's LAYER_BEGIN counts a layer's channels
#: (solid mask included) in one byte.
MAX_PART_MATERIALS = 254


@dataclass(frozen=True)
class PartsPlan:
    """How a multi-part job's parts become masks: per part (in part-label order) its name, material (index
    into ``materials``, the droplet-mask materials in mask order) and given priority (None: default);
    ``order``, the part labels ranked (the first wins where parts overlap); ``channels``, whether droplet
    masks are written (more than one material, or asked for)."""

    names: tuple[str, ...]
    materials: tuple[Material, ...]
    part_material: tuple[int, ...]
    priorities: tuple[int | None, ...]
    order: tuple[int, ...]
    channels: bool

    def channel_materials(self) -> tuple[Material, ...]:
        """The droplet masks' materials in mask order, by printer channel and unassigned last (none without
        droplet masks)."""
        return self.materials if self.channels else ()


def part_order(volumes: Sequence[float], priorities: Sequence[int | None]) -> tuple[int, ...]:
    """Part indices ranked for overlaps, the winner first: higher priority first (None counts as 0), then the
    smaller volume (mm^3), then the part listed first."""
    return tuple(sorted(range(len(volumes)), key=lambda i: (-(priorities[i] or 0), volumes[i], i)))


def _part_material(part: Part, setting: PartSetting | None, table: dict[str, Material],
                   palette: tuple[Material, ...]) -> Material:
    """A part's material: the one its setting names, else the table material its file names for it (a 3MF
    base material), else the table material nearest its one colour; InputError naming the part's file."""
    if setting is not None:
        material = table_material(setting.material, table)
        if material is None:
            raise InputError(f"parts: {part.name}: unknown material {setting.material!r} "
                             f"(materials: {', '.join(table)})")
        return material
    named = table_material(part.material_name, table) if part.material_name else None
    if named is not None:
        return named
    if part.color is not None:
        return palette[int(nearest_materials(np.array([part.color]), palette)[0])]
    raise InputError(f"{part.source}: part {part.name!r} has no material: name one for it in the materials "
                     f"file's [parts] table or with --part {part.name}=MATERIAL (it has no single colour to map)")


def plan_parts(parts: Sequence[Part], table: dict[str, Material], settings: Mapping[str, PartSetting],
               channels: bool = False) -> PartsPlan:
    """The :class:`PartsPlan` of ``parts`` with the materials ``table`` and the per-part ``settings`` (by part
    name); ``channels`` asks for droplet masks even when every part has the same material.

    A job of one part that nothing maps takes the table's first material. The droplet masks' materials are
    those the parts use, ordered by printer channel (unassigned last,
    then in the table's order). Raises InputError for a setting naming no part, an unknown material, two
    used materials on one printer channel or more materials than a layer's channels can carry.
    """
    names = [part.name for part in parts]
    unknown = [name for name in settings if name not in names]
    if unknown:
        raise InputError(f"parts: no part named {unknown[0]!r} in this job (its parts: {', '.join(names)})")
    palette = tuple(table.values())
    if len(parts) == 1 and parts[0].name not in settings and parts[0].color is None and (
            table_material(parts[0].material_name or "", table) is None):
        chosen = [palette[0]]  # one plain part (an uncoloured one-object 3MF): the table's first material
    else:
        chosen = [_part_material(part, settings.get(part.name), table, palette) for part in parts]
    rank = {material.name: position for position, material in enumerate(palette)}
    used = sorted({material.name: material for material in chosen}.values(),
                  key=lambda m: (m.channel is None, m.channel or 0, rank.get(m.name, len(rank))))
    if len(used) > MAX_PART_MATERIALS:
        raise InputError(f"parts: {len(used)} materials, more than the {MAX_PART_MATERIALS} droplet masks a layer "
                         "can carry")
    check_one_per_channel(used, "the parts")
    files = [channel_name(material) for material in used]
    if len(set(files)) != len(files):
        raise InputError(f"materials: material names give the same droplet-mask file names ({files}); rename them")
    position = {material.name: index for index, material in enumerate(used)}
    priorities = tuple(settings[name].priority if name in settings else None for name in names)
    return PartsPlan(names=tuple(names), materials=tuple(used),
                     part_material=tuple(position[material.name] for material in chosen), priorities=priorities,
                     order=part_order([part.volume_mm3 for part in parts], priorities),
                     channels=channels or len(used) > 1)


def compose_part_masks(part_masks: Mapping[int, np.ndarray], plan: PartsPlan, shape: tuple[int, int]
                       ) -> tuple[np.ndarray, list[np.ndarray]]:
    """The solid mask (the union) and one mask per material of packed part masks ({part label: (h, ceil(w / 8))
    uint8}): each pixel goes to the material of the first part in ``plan.order`` that holds it."""
    claimed = np.zeros(shape, dtype=np.uint8)
    planes = [np.zeros(shape, dtype=np.uint8) for _ in plan.materials]
    for label in plan.order:
        mask = part_masks.get(label)
        if mask is None:
            continue
        planes[plan.part_material[label]] |= mask & ~claimed
        claimed |= mask
    return claimed, planes


def part_layer_masks(points: np.ndarray, offsets: np.ndarray, loop_part: np.ndarray, grid: Grid
                     ) -> dict[int, np.ndarray]:
    """{part label: packed mask of that part's loops} of one layer (points (p, 2) mm, offsets (l + 1,),
    loop_part (l,) part label per loop)."""
    lengths = np.diff(offsets)
    masks = {}
    for label in np.unique(loop_part):
        chosen = loop_part == label
        own = np.concatenate([[0], np.cumsum(lengths[chosen])])
        masks[int(label)] = packed_mask(points[np.repeat(chosen, lengths)], own, grid)
    return masks


def render_parts_run(contours: Contours, context: RunContext, first_layer: int) -> list[tuple]:
    """Render and write the layers of one run's ``contours`` (layer k is stack layer first_layer + k) as
    :func:`heoslice.pipeline.layer_job.render_and_write` does: (index, sha256, solid pixels, raster s,
    encode s, channel entries (file name, sha256, set pixels)) per layer."""
    spec, grid, plan = context.spec, context.grid, context.spec.parts
    loop_part = context.mesh.part[contours.face] if len(contours.face) else np.zeros(0, np.int64)
    shape = (grid.height, -(-grid.width // 8))
    # a stack with droplet masks is a multi-material stack; one part material gives a one-material stack
    level = deflate_level(bool(plan.channel_materials()))
    masks_encoder, masks_level = mask_deflation(None)  # part masks: no halftone made them
    done = []
    for local in range(len(contours.layer_offsets) - 1):
        index = first_layer + local
        first, last = contours.layer_offsets[local], contours.layer_offsets[local + 1]
        start = contours.offsets[first]
        started = time.perf_counter()
        masks = part_layer_masks(contours.points[start:contours.offsets[last]],
                                 contours.offsets[first:last + 1] - start, loop_part[first:last], grid)
        solid, planes = compose_part_masks(masks, plan, shape)
        rendered = time.perf_counter()
        data = encode_bilevel_tiff(solid, grid.width, spec.dpi, spec.compression, spec.layer_height_mm, level=level)
        pieces = [(layer_file_name(index, channel_name(material)),
                   encode_bilevel_tiff(plane, grid.width, spec.dpi, spec.compression, spec.layer_height_mm,
                                       level=masks_level, encoder=masks_encoder),
                   count_solid(plane))
                  for material, plane in zip(plan.channel_materials(), planes)]
        encoded = time.perf_counter()
        digest = write_file(context.directory / layer_file_name(index), data)
        channels = tuple((name, write_file(context.directory / name, blob), count) for name, blob, count in pieces)
        done.append((index, digest, count_solid(solid), rendered - started, encoded - rendered, channels))
    return done


def parts_records(parts: Sequence[Part], plan: PartsPlan, volumes: Sequence[float] | None = None) -> list[dict]:
    """The manifest's ``parts`` list: per part its name, file, file SHA-256, material, given priority, rank
    (0 wins over every part it overlaps) and designed volume (mm^3: its own less what parts ranked before it
    take, :func:`heoslice.mesh.ranked_part_volumes_mm3`; None when not known)."""
    rank = {label: position for position, label in enumerate(plan.order)}
    return [{"name": part.name, "file": Path(part.source).name, "sha256": part.sha256,
             "material": plan.materials[plan.part_material[label]].name, "priority": plan.priorities[label],
             "rank": rank[label], "volume_mm3": None if volumes is None else float(volumes[label])}
            for label, part in enumerate(parts)]
