"""The volume slice job: a label map in, the same stack as the mesh route out (issue 45).

label map -> which labels print in which material (:func:`plan_labels`, the materials file's [labels]
table) -> each printed label's smooth field (:mod:`heoslice.volume.fields`) -> layer by layer, the solid
mask and one droplet mask per material (:func:`heoslice.volume.resample.layer_masks`) written as the mesh
route writes them -> the manifest last, recording where the print sits in the scan's space. Memory: the
volume, the fields and one layer; never the stack.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from heoslice.errors import InputError
from heoslice.layers.planes import layer_count, plane_heights
from heoslice.layers.rasterising import grid_for
from heoslice.locks import hold_stack
from heoslice.material import Material, PartSetting, check_one_per_channel, table_material
from heoslice.pipeline.parts import MAX_PART_MATERIALS, part_order
from heoslice.pipeline.spec import SliceSpec, StageTimes, channel_name
from heoslice.stack import (
    ChannelRecord,
    ImageRecord,
    LayerRecord,
    build_manifest,
    check_image_size,
    droplet_summary,
    encode_bilevel_tiff,
    layer_file_name,
    max_layer_count,
    prepare_directory,
    write_file,
    write_manifest,
)
from heoslice.stack.tiff import deflate_level
from heoslice.volume import Label, Volume
from heoslice.volume.info import label_counts
from heoslice.volume.placement import place
from heoslice.volume.resample import label_print, layer_masks


@dataclass(frozen=True)
class LabelPlan:
    """Which labels print and how: the printed labels (with voxels), each one's material (index into
    ``materials``, the droplet masks' materials in mask order), their voxel counts, ranks where they overlap
    (None for a label map, whose labels cannot), and whether droplet masks are written."""

    labels: tuple[Label, ...]
    materials: tuple[Material, ...]
    label_material: tuple[int, ...]
    voxels: tuple[int, ...]
    ranks: tuple[int, ...] | None
    channels: bool
    warnings: tuple[str, ...] = ()

    def records(self) -> list[dict]:
        """The manifest's ``labels`` list: per printed label its value, name, layer, material and voxels."""
        return [{"value": label.value, "name": label.name, "layer": label.layer,
                 "material": self.materials[material].name, "voxels": voxels}
                for label, material, voxels in zip(self.labels, self.label_material, self.voxels)]


def _matches(key: str, labels: tuple[Label, ...]) -> list[int]:
    """Indices of the labels a [labels] key names: a whole number is a label value, anything else a segment
    or structure name (case ignored)."""
    text = str(key).strip()
    if text.lstrip("-").isdigit():
        return [index for index, label in enumerate(labels) if label.value == int(text)]
    return [index for index, label in enumerate(labels) if label.name and label.name.lower() == text.lower()]


def plan_labels(volume: Volume, table: dict[str, Material], settings: Mapping[str, PartSetting] | None,
                channels: bool = False) -> LabelPlan:
    """The :class:`LabelPlan` of ``volume`` with the materials ``table`` and the [labels] ``settings``.

    Without a [labels] table (None) every label prints, in the table's first material. With one, only the
    labels it lists print, each in its material; a key that names no label of the file is an InputError,
    and so is a label named twice. Listed labels without voxels are left out with a warning.
    """
    counts = label_counts(volume)
    chosen: dict[int, PartSetting] = {}
    if settings is None:
        first = next(iter(table))
        chosen = {index: PartSetting(first) for index in range(len(volume.labels))}
    else:
        for key, setting in settings.items():
            found = _matches(key, volume.labels)
            if not found:
                known = ", ".join(label.describe() for label in volume.labels[:12])
                more = " ..." if len(volume.labels) > 12 else ""
                raise InputError(f"{volume.source}: [labels] {key}: no such label in the file (its labels: "
                                 f"{known or 'none'}{more})")
            for index in found:
                if index in chosen:
                    raise InputError(f"{volume.source}: [labels]: label {volume.labels[index].describe()} is listed "
                                     "twice")
                chosen[index] = setting
    empty = [volume.labels[index].describe() for index in sorted(chosen) if counts[index] == 0]
    printed = [index for index in sorted(chosen) if counts[index] > 0]
    if not printed:
        raise InputError(f"{volume.source}: no label to print (the [labels] table lists none with voxels)")
    materials_of = [table_material(chosen[index].material, table) for index in printed]
    rank = {material.name: position for position, material in enumerate(table.values())}
    used = sorted({material.name: material for material in materials_of}.values(),
                  key=lambda m: (m.channel is None, m.channel or 0, rank.get(m.name, len(rank))))
    if len(used) > MAX_PART_MATERIALS:
        raise InputError(f"labels: {len(used)} materials, more than the {MAX_PART_MATERIALS} a layer can carry")
    check_one_per_channel(used, "the labels")
    position = {material.name: index for index, material in enumerate(used)}
    voxels = tuple(counts[index] for index in printed)
    ranks = None
    if volume.layer_count > 1:
        order = part_order([float(v) for v in voxels], [chosen[index].priority for index in printed])
        ranks = tuple(order.index(index) for index in range(len(printed)))
    warnings = tuple(f"[labels]: label {name} has no voxels: left out" for name in empty)
    return LabelPlan(tuple(volume.labels[index] for index in printed), tuple(used),
                     tuple(position[material.name] for material in materials_of), voxels, ranks,
                     channels or len(used) > 1, warnings)


def slice_volume_to_stack(volume: Volume, directory: Path, spec: SliceSpec, plan: LabelPlan, *, up: str = "S",
                          smooth: float | None = None, force: bool = False,
                          progress: Callable[[int, int], None] | None = None) -> tuple[dict, StageTimes]:
    """Slice the label map ``volume`` into a stack in ``directory`` as ``plan`` says, printer +z the
    anatomical direction ``up``; the manifest (written last) and stage timings."""
    directory = Path(directory)
    times = StageTimes()
    started = time.perf_counter()
    placement = place(volume, up)
    prepared = label_print(volume, placement, [(label, material + 1) for label, material in
                                               zip(plan.labels, plan.label_material)], smooth,
                           None if plan.ranks is None else list(plan.ranks))
    times.slice = time.perf_counter() - started
    bounds = prepared.bounds_mm()
    grid = grid_for(bounds[:, :2], spec.dpi, spec.margin_mm, spec.canvas_mm)
    check_image_size(grid.width, grid.height)
    masks = plan.materials if plan.channels else ()
    limit = max_layer_count([channel_name(m) for m in masks])
    if layer_count(bounds[0, 2], bounds[1, 2], spec.layer_height_mm, limit) > limit:
        raise InputError(f"layer_height_mm: {spec.layer_height_mm:g} mm gives more than {limit} layers for this "
                         f"volume's {float(bounds[1, 2] - bounds[0, 2]):g} mm (the most one stack's manifest holds)")
    level = deflate_level(bool(masks))
    with ExitStack() as held:
        existed = directory.is_dir()
        if existed:
            held.enter_context(hold_stack(directory, "slicing into it"))
        prepare_directory(directory, force)
        if not existed:
            held.enter_context(hold_stack(directory, "slicing into it"))
        z = plane_heights(bounds[0, 2], bounds[1, 2], spec.layer_height_mm)
        layers = []
        for index, height in enumerate(z):
            began = time.perf_counter()
            planes, counts = layer_masks(prepared, float(height), grid, len(plan.materials))
            rendered = time.perf_counter()
            encode = lambda plane: encode_bilevel_tiff(plane, grid.width, spec.dpi, spec.compression,  # noqa: E731
                                                       spec.layer_height_mm, level=level)
            solid = encode(planes[0])
            pieces = [(layer_file_name(index, channel_name(material)), encode(planes[number + 1]),
                       int(counts[number + 1])) for number, material in enumerate(masks)]
            encoded = time.perf_counter()
            digest = write_file(directory / layer_file_name(index), solid)
            channels = None if not masks else tuple(
                ChannelRecord(material.name, name, write_file(directory / name, data), count)
                for material, (name, data, count) in zip(masks, pieces))
            layers.append(LayerRecord(float(height), digest, int(counts[0]), False, channels))
            times.raster += rendered - began
            times.encode += encoded - rendered
            if progress is not None:
                progress(index + 1, len(z))
        manifest = build_manifest(
            source_file=volume.source.name, source_sha256=volume.sha256, layer_height_mm=spec.layer_height_mm,
            dpi=spec.dpi, pixel_size_mm=(grid.px, grid.py),
            image=ImageRecord(grid.width, grid.height, (grid.x_left, grid.y_top), "1", spec.compression),
            z_range_mm=(float(bounds[0, 2]), float(bounds[1, 2])), warnings=[*volume.warnings, *plan.warnings],
            layers=layers, grading=droplet_summary(masks) if masks else None,
            placement=placement.record(volume.space, (grid.x_left, grid.y_top, float(bounds[0, 2]))),
            labels=plan.records())
        write_manifest(directory, manifest)
    times.total = time.perf_counter() - started
    return manifest, times


def slice_intensity_to_stack(volume: Volume, directory: Path, spec: SliceSpec, curve, *, up: str = "S",
                             force: bool = False, progress: Callable[[int, int], None] | None = None
                             ) -> tuple[dict, StageTimes]:
    """Slice an intensity volume (a CT) into a stack: per layer the values interpolated at the pixels, solid
    where they reach the curve's first point, each solid pixel's blend of materials from ``curve``
    (:class:`heoslice.volume.intensity.IntensityCurve`) halftoned into one droplet mask per material."""
    from heoslice.volume.intensity import halftone_mix, intensity_plane

    directory = Path(directory)
    times = StageTimes()
    started = time.perf_counter()
    placement = place(volume, up)
    oriented = placement.orient(volume.data)
    origin, spacing = placement.oriented_origin(volume.shape), placement.spacing
    printed = np.argwhere(oriented >= curve.values[0])
    if not len(printed):
        raise InputError(f"{volume.source}: no voxel reaches the curve's first value ({curve.values[0]:g}): nothing "
                         "to print")
    low = origin + (printed.min(axis=0) - 1.0) * spacing
    high = origin + (printed.max(axis=0) + 1.0) * spacing
    bounds = np.stack([low[::-1], high[::-1]])
    grid = grid_for(bounds[:, :2], spec.dpi, spec.margin_mm, spec.canvas_mm)
    check_image_size(grid.width, grid.height)
    masks = curve.materials
    limit = max_layer_count([channel_name(m) for m in masks])
    if layer_count(bounds[0, 2], bounds[1, 2], spec.layer_height_mm, limit) > limit:
        raise InputError(f"layer_height_mm: {spec.layer_height_mm:g} mm gives more than {limit} layers for this "
                         f"volume's {float(bounds[1, 2] - bounds[0, 2]):g} mm (the most one stack's manifest holds)")
    level = deflate_level(True)
    with ExitStack() as held:
        existed = directory.is_dir()
        if existed:
            held.enter_context(hold_stack(directory, "slicing into it"))
        prepare_directory(directory, force)
        if not existed:
            held.enter_context(hold_stack(directory, "slicing into it"))
        z = plane_heights(bounds[0, 2], bounds[1, 2], spec.layer_height_mm)
        layers = []
        for index, height in enumerate(z):
            began = time.perf_counter()
            values, inside = intensity_plane(oriented, origin, spacing, float(height), grid)
            solid = inside & (values >= curve.values[0])
            planes = halftone_mix(curve.mix(values), solid, index)
            rendered = time.perf_counter()
            encode = lambda bits: encode_bilevel_tiff(np.packbits(bits, axis=1), grid.width, spec.dpi,  # noqa: E731
                                                      spec.compression, spec.layer_height_mm, level=level)
            digest = write_file(directory / layer_file_name(index), encode(solid))
            channels = tuple(ChannelRecord(material.name, layer_file_name(index, channel_name(material)),
                                           write_file(directory / layer_file_name(index, channel_name(material)),
                                                      encode(plane)), int(plane.sum()))
                             for material, plane in zip(masks, planes))
            layers.append(LayerRecord(float(height), digest, int(solid.sum()), False, channels))
            times.raster += rendered - began
            times.encode += time.perf_counter() - rendered
            if progress is not None:
                progress(index + 1, len(z))
        manifest = build_manifest(
            source_file=volume.source.name, source_sha256=volume.sha256, layer_height_mm=spec.layer_height_mm,
            dpi=spec.dpi, pixel_size_mm=(grid.px, grid.py),
            image=ImageRecord(grid.width, grid.height, (grid.x_left, grid.y_top), "1", spec.compression),
            z_range_mm=(float(bounds[0, 2]), float(bounds[1, 2])), warnings=list(volume.warnings), layers=layers,
            grading=droplet_summary(masks),
            placement=placement.record(volume.space, (grid.x_left, grid.y_top, float(bounds[0, 2]))))
        write_manifest(directory, manifest)
    times.total = time.perf_counter() - started
    return manifest, times
