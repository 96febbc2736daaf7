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
from contextlib import ExitStack, closing
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from heoslice.errors import InputError
from heoslice.layers.planes import layer_count, plane_heights
from heoslice.layers.rasterising import grid_for
from heoslice.locks import hold_stack
from heoslice.material import Material, PartSetting, check_one_per_channel, table_material
from heoslice.pipeline.parts import MAX_PART_MATERIALS, part_order
from heoslice.pipeline.printers import check_printer_materials, printer_grid
from heoslice.pipeline.spec import SliceSpec, StageTimes, channel_name
from heoslice.pipeline.volume_grading import GradeSetting, grade_field, resolve_grades
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
from heoslice.stack.tiff import Deflation, deflate_level, mask_deflation
from heoslice.volume import Label, Volume
from heoslice.volume.info import label_counts
from heoslice.volume.model import labels_named
from heoslice.volume.placement import place
from heoslice.volume.resample import label_print, layer_masks


@dataclass(frozen=True)
class LabelPlan:
    """Which labels print and how: the printed labels (with voxels), each one's material (index into
    ``materials``, the droplet masks' materials in mask order), their voxel counts, ranks where they overlap
    (None for a label map, whose labels cannot), whether droplet masks are written, and each one's [labels]
    ``priority`` (0 when not given: in a label map, it decides a pixel two labels' fields both claim)."""

    labels: tuple[Label, ...]
    materials: tuple[Material, ...]
    label_material: tuple[int, ...]
    voxels: tuple[int, ...]
    ranks: tuple[int, ...] | None
    channels: bool
    warnings: tuple[str, ...] = ()
    priorities: tuple[int, ...] = ()

    def records(self) -> list[dict]:
        """The manifest's ``labels`` list: per printed label its value, name, layer, material and voxels."""
        return [{"value": label.value, "name": label.name, "layer": label.layer,
                 "material": self.materials[material].name, "voxels": voxels}
                for label, material, voxels in zip(self.labels, self.label_material, self.voxels)]


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
            found = labels_named(key, volume.labels)
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
    used = _mask_order(materials_of, "the labels", tuple(table))
    position = {material.name: index for index, material in enumerate(used)}
    voxels = tuple(counts[index] for index in printed)
    priorities = tuple(chosen[index].priority or 0 for index in printed)
    ranks = None
    if volume.layer_count > 1:
        order = part_order([float(v) for v in voxels], list(priorities))
        ranks = tuple(order.index(index) for index in range(len(printed)))
    warnings = tuple(f"[labels]: label {name} has no voxels: left out" for name in empty)
    return LabelPlan(tuple(volume.labels[index] for index in printed), tuple(used),
                     tuple(position[material.name] for material in materials_of), voxels, ranks,
                     channels or len(used) > 1, warnings, priorities)


def _check_layers(spec: SliceSpec, bounds: np.ndarray, masks: tuple[Material, ...]) -> None:
    """Refuse a layer count above what one stack with droplet masks of ``masks`` holds, before slicing."""
    limit = max_layer_count([channel_name(m) for m in masks])
    if layer_count(bounds[0, 2], bounds[1, 2], spec.layer_height_mm, limit) > limit:
        raise InputError(f"layer_height_mm: {spec.layer_height_mm:g} mm gives more than {limit} layers for this "
                         f"volume's {float(bounds[1, 2] - bounds[0, 2]):g} mm (the most one stack's manifest holds)")


def _layer_files(directory: Path, spec: SliceSpec, grid, masks: tuple[Material, ...],
                 deflations: tuple[Deflation, Deflation], render: Callable[[int, float], tuple[np.ndarray, np.ndarray]],
                 index: int, height: float) -> tuple[LayerRecord, float, float]:
    """Render, encode and write layer ``index`` at ``height`` mm (``deflations``: how its solid mask and its droplet
    masks are deflated): its record, and the CPU seconds of its render and of its encoding and writing."""
    began = time.process_time()
    planes, counts = render(index, height)
    rendered = time.process_time()
    encoded = [encode_bilevel_tiff(plane, grid.width, spec.dpi, spec.compression, spec.layer_height_mm,
                                   level=deflations[number > 0].level, encoder=deflations[number > 0].encoder)
               for number, plane in enumerate(planes[:1 + len(masks)])]
    digest = write_file(directory / layer_file_name(index), encoded[0])
    channels = None if not masks else tuple(
        ChannelRecord(material.name, layer_file_name(index, channel_name(material)),
                      write_file(directory / layer_file_name(index, channel_name(material)), data), int(count))
        for material, data, count in zip(masks, encoded[1:], counts[1:]))
    return LayerRecord(float(height), digest, int(counts[0]), False, channels), rendered - began, \
        time.process_time() - rendered


def _write_stack(directory: Path, spec: SliceSpec, grid, bounds: np.ndarray, masks: tuple[Material, ...],
                 render: Callable[[int, float], tuple[np.ndarray, np.ndarray]], manifest_fields: dict, times: StageTimes,
                 force: bool, progress: Callable[[int, int], None] | None, halftone: str | None = None
                 ) -> dict:
    """Write a volume's stack as the mesh route writes one: ``render(index, z)`` gives a layer's packed planes
    ((1 + len(masks), H, ceil(W / 8)) uint8: the solid mask, then one droplet mask per material of ``masks``,
    none for a one-material stack) and their set pixels; the layers are rendered, encoded and written over
    ``spec``'s worker processes (:func:`heoslice.pipeline.parallel.ordered_map`), the manifest last. Returns it.
    ``halftone`` is the method that made the droplet masks (None: nothing was halftoned, each pixel is one
    label's material): recorded as the manifest's ``grading.halftone`` as the mesh route records it (omitted for
    ordered dither), so that a stack says how its mixes became droplets."""
    from heoslice.pipeline.parallel import ordered_map

    check_printer_materials(spec.printer, len(masks))
    deflations = (Deflation("zlib-ng", deflate_level(bool(masks))), mask_deflation(halftone))
    with ExitStack() as held:
        existed = directory.is_dir()
        if existed:
            held.enter_context(hold_stack(directory, "slicing into it"))
        prepare_directory(directory, force)
        if not existed:
            held.enter_context(hold_stack(directory, "slicing into it"))
        z = plane_heights(bounds[0, 2], bounds[1, 2], spec.layer_height_mm)
        layers = []
        done = held.enter_context(closing(ordered_map(
            lambda index: _layer_files(directory, spec, grid, masks, deflations, render, index, float(z[index])),
            range(len(z)), spec.worker_count())))
        for record, raster, encode in done:
            layers.append(record)
            times.raster += raster
            times.encode += encode
            if progress is not None:
                progress(len(layers), len(z))
        manifest = build_manifest(
            layer_height_mm=spec.layer_height_mm, dpi=spec.dpi, pixel_size_mm=(grid.px, grid.py),
            image=ImageRecord(grid.width, grid.height, (grid.x_left, grid.y_top), "1", spec.compression),
            z_range_mm=(float(bounds[0, 2]), float(bounds[1, 2])), layers=layers,
            grading=_droplet_grading(masks, halftone), **manifest_fields)
        write_manifest(directory, manifest)
    return manifest


def _droplet_grading(masks: tuple[Material, ...], halftone: str | None) -> dict | None:
    """The manifest's ``grading`` of a volume's stack: None without droplet masks, else their materials and the
    ``halftone`` method (:func:`heoslice.stack.droplet_summary`)."""
    if not masks:
        return None
    return droplet_summary(masks, halftone)


def _grid(spec: SliceSpec, bounds: np.ndarray):
    """The layer grid over ``bounds`` ((2, 3) mm), padded as ``spec``'s printer preset takes it, within the size
    limit."""
    grid = printer_grid(grid_for(bounds[:, :2], spec.dpi, spec.margin_mm, spec.canvas_mm), spec.printer)
    check_image_size(grid.width, grid.height)
    return grid


def _mask_order(materials: list[Material], needing: str, table_order: tuple[str, ...] = ()) -> tuple[Material, ...]:
    """The droplet masks' materials, the one rule every volume job orders and checks them by: ``materials`` once
    each (by name), ordered by printer channel (those without one last); ties by their place in ``table_order``
    (the materials table's names, when the order comes from it), then by first appearance. Refused
    (InputError, ``needing`` saying who needs the masks): more than :data:`MAX_PART_MATERIALS` materials, or
    two on one printer channel."""
    used = {m.name: m for m in materials}
    first = {name: position for position, name in enumerate(used)}
    listed = {name: position for position, name in enumerate(table_order)}
    masks = tuple(sorted(used.values(), key=lambda m: (m.channel is None, m.channel or 0,
                                                       listed.get(m.name, len(listed)), first[m.name])))
    if len(masks) > MAX_PART_MATERIALS:
        raise InputError(f"labels: {len(masks)} materials, more than the {MAX_PART_MATERIALS} a layer can carry")
    check_one_per_channel(masks, needing)
    return masks


def slice_volume_to_stack(volume: Volume, directory: Path, spec: SliceSpec, plan: LabelPlan, *, up: str = "S",
                          smooth: float | None = None, force: bool = False,
                          progress: Callable[[int, int], None] | None = None,
                          grades: tuple[GradeSetting, ...] = ()) -> tuple[dict, StageTimes]:
    """Slice the label map ``volume`` into a stack in ``directory`` as ``plan`` says, printer +z the
    anatomical direction ``up``; the manifest (written last) and stage timings. ``grades`` ([grade]) grade
    labels inside by distance (:mod:`heoslice.pipeline.volume_grading`): each graded label's pixels get its own
    code, and its share f(r) of M2 at each of them is halftoned into M1's and M2's droplet masks."""
    times = StageTimes()
    started = time.perf_counter()
    placement = place(volume, up)
    starts = [plan.materials[material] for material in plan.label_material]
    graded = resolve_grades(grades, volume, plan.labels, starts)
    masks = _mask_order([*plan.materials, *(grade.target for grade in graded)], "the labels and their grading") \
        if graded else plan.materials if plan.channels else ()  # plan.materials: ordered and checked by plan_labels
    position = {material.name: index for index, material in enumerate(masks)}
    codes = [position[material.name] + 1 if masks else 0 for material in starts]  # 0: the solid mask only
    for number, grade in enumerate(graded):
        codes[grade.index] = len(masks) + 1 + number
    prepared = label_print(volume, placement, list(zip(plan.labels, codes)), smooth,
                           None if plan.ranks is None else list(plan.ranks), list(plan.priorities))
    fields = [_grade_field(volume, placement, prepared, plan, grade, smooth) for grade in graded]
    times.slice = time.perf_counter() - started
    bounds = prepared.bounds_mm()
    grid = _grid(spec, bounds)
    _check_layers(spec, bounds, masks)
    kinds = len(masks)

    def render(index: int, z: float) -> tuple[np.ndarray, np.ndarray]:
        from heoslice.grading.pixel_mix import fraction_planes

        packed, counts = layer_masks(prepared, z, grid, kinds + len(graded))
        if not graded:
            return packed, counts
        planes = packed[:1 + kinds]
        for number, (grade, field) in enumerate(zip(graded, fields)):
            own = packed[1 + kinds + number]
            if own.any():
                box, f = field.layer_fraction(own, grid, z)
                planes[1:] |= fraction_planes(own, box, f, grid, index, position[grade.start.name],
                                              position[grade.target.name], kinds, spec.halftone)
        return planes, np.bitwise_count(planes).reshape(len(planes), -1).sum(axis=1, dtype=np.int64)

    records = plan.records()
    for grade in graded:
        records[grade.index]["grading"] = {**grade.setting.record(), "toward": grade.reference.describe(),
                                           "range_mm": list(fields[graded.index(grade)].design.r_range)}
    manifest = _write_stack(
        Path(directory), spec, grid, bounds, masks, render,
        {"source_file": volume.source.name, "source_sha256": volume.sha256,
         "warnings": [*volume.warnings, *plan.warnings],
         "placement": placement.record(volume.space, (grid.x_left, grid.y_top, float(bounds[0, 2]))),
         "labels": records}, times, force, progress, spec.halftone if graded else None)
    times.total = time.perf_counter() - started
    return manifest, times


def _grade_field(volume: Volume, placement, prepared, plan: LabelPlan, grade, smooth: float | None):
    """A graded label's material field: its reference label's reconstructed surface (the printed label's own
    field, or the reference label's computed alike) and the graded label's voxel centres (printer mm)."""
    from heoslice.volume.surface import label_surface

    if grade.reference in plan.labels:
        reference = prepared.fields[plan.labels.index(grade.reference)]
    else:
        reference = label_print(volume, placement, [(grade.reference, 1)], smooth).fields[0]
    label = plan.labels[grade.index]
    voxels = np.argwhere(placement.orient(volume.layer(label.layer)) == label.value)
    centres = (prepared.origin + voxels * prepared.spacing)[:, ::-1]
    return grade_field(grade, *label_surface(reference, prepared.origin, prepared.spacing), centres)


def _packed(masks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(packed (n, H, ceil(W / 8)) uint8, set pixels (n,) int64) of boolean masks (n, H, W)."""
    return np.packbits(masks, axis=2), masks.reshape(len(masks), -1).sum(axis=1)


def slice_intensity_to_stack(volume: Volume, directory: Path, spec: SliceSpec, curve, *, up: str = "S",
                             force: bool = False, progress: Callable[[int, int], None] | None = None
                             ) -> tuple[dict, StageTimes]:
    """Slice an intensity volume (a CT) into a stack: per layer the values interpolated at the pixels, solid
    where they reach the curve's first point, each solid pixel's blend of materials from ``curve``
    (:class:`heoslice.volume.intensity.IntensityCurve`) halftoned into one droplet mask per material."""
    from heoslice.grading.halftone import halftone
    from heoslice.volume.intensity import intensity_plane

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
    grid = _grid(spec, bounds)
    _check_layers(spec, bounds, curve.materials)

    def render(index: int, z: float) -> tuple[np.ndarray, np.ndarray]:
        values, inside = intensity_plane(oriented, origin, spacing, z, grid)
        solid = inside & (values >= curve.values[0])
        return _packed(np.concatenate([solid[None], halftone(curve.mix(values) * solid[..., None], index,
                                                              spec.halftone)]))

    manifest = _write_stack(
        Path(directory), spec, grid, bounds, curve.materials, render,
        {"source_file": volume.source.name, "source_sha256": volume.sha256, "warnings": list(volume.warnings),
         "placement": placement.record(volume.space, (grid.x_left, grid.y_top, float(bounds[0, 2])))},
        times, force, progress, spec.halftone)
    times.total = time.perf_counter() - started
    return manifest, times


def slice_ct_with_labels_to_stack(ct: Volume, labels: Volume, directory: Path, spec: SliceSpec, plan: LabelPlan,
                                  curve, curve_labels: frozenset[int], *, up: str = "S", smooth: float | None = None,
                                  force: bool = False, progress: Callable[[int, int], None] | None = None
                                  ) -> tuple[dict, StageTimes]:
    """One job of a CT and its label map on the same grid: the labels of ``plan`` print as the label route
    prints them, except those whose index in ``plan.labels`` is in ``curve_labels``: inside them each pixel's
    material follows the CT's value through ``curve`` (bone by its density), halftoned. The droplet masks'
    materials are the labels' and the curve's, ordered by printer channel."""
    from heoslice.grading.halftone import halftone
    from heoslice.volume.intensity import intensity_plane

    if ct.shape != labels.shape or not np.allclose(ct.ras_affine(), labels.ras_affine(), atol=1e-3):
        raise InputError(f"{labels.source}: not on the grid of {ct.source} (shape and affine must agree)")
    times = StageTimes()
    started = time.perf_counter()
    placement = place(labels, up)
    ct_placement = place(ct, up)
    oriented = ct_placement.orient(ct.data)
    origin, spacing = ct_placement.oriented_origin(ct.shape), ct_placement.spacing
    label_materials = [plan.materials[material] for index, material in enumerate(plan.label_material)
                       if index not in curve_labels]
    masks = _mask_order([*label_materials, *curve.materials], "the labels and the intensity curve")
    position = {m.name: index for index, m in enumerate(masks)}
    curve_code = len(masks) + 1
    codes = [curve_code if index in curve_labels else position[plan.materials[material].name] + 1
             for index, material in enumerate(plan.label_material)]
    prepared = label_print(labels, placement, list(zip(plan.labels, codes)), smooth,
                           None if plan.ranks is None else list(plan.ranks), list(plan.priorities))
    times.slice = time.perf_counter() - started
    bounds = prepared.bounds_mm()
    grid = _grid(spec, bounds)
    _check_layers(spec, bounds, masks)
    curve_columns = [position[m.name] for m in curve.materials]

    def render(index: int, z: float) -> tuple[np.ndarray, np.ndarray]:
        packed, _ = layer_masks(prepared, z, grid, curve_code)  # the last plane: the curve's labels' pixels
        planes = np.unpackbits(packed, axis=2, count=grid.width).astype(bool)[:-1]
        inside = np.unpackbits(packed[-1], axis=1, count=grid.width).astype(bool)
        if inside.any():
            values, covered = intensity_plane(oriented, origin, spacing, z, grid)
            air = inside & ~(covered & (values >= curve.values[0]))  # below the curve's first point, as a CT alone
            planes[0] &= ~air
            blend = halftone(curve.mix(values) * (inside & ~air)[..., None], index, spec.halftone)
            for column, plane in zip(curve_columns, blend):
                planes[column + 1] |= plane
        return _packed(planes)

    records = plan.records()
    for index in curve_labels:
        records[index]["material"] = "intensity curve"
    manifest = _write_stack(
        Path(directory), spec, grid, bounds, masks, render,
        {"source_file": labels.source.name, "source_sha256": labels.sha256,
         "warnings": [*ct.warnings, *labels.warnings, *plan.warnings],
         "placement": placement.record(labels.space, (grid.x_left, grid.y_top, float(bounds[0, 2]))),
         "labels": records}, times, force, progress, spec.halftone if curve_labels else None)
    times.total = time.perf_counter() - started
    return manifest, times
