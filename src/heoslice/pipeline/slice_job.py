"""The slice job: mesh -> planes -> runs of layers (sliced, chained, rendered, written) -> manifest.

:func:`slice_to_stack` checks the job's sizes before anything is written, prepares the directory, has
every run of planes done (:func:`heoslice.pipeline.parallel.run_all`, streaming each layer to disk as
soon as it is done, so memory does not grow with the number of layers) and writes the manifest last.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import ExitStack, contextmanager
from pathlib import Path

import numpy as np

from heoslice.errors import InputError
from heoslice.layers.planes import layer_count, plane_heights
from heoslice.layers.rasterising import grid_for
from heoslice.layers.slicing import face_z_range
from heoslice.locks import hold_stack
from heoslice.mesh import Mesh, ranked_part_volumes_mm3
from heoslice.pipeline.materials import colour_collapse, material_job
from heoslice.pipeline.parallel import run_all
from heoslice.pipeline.parts import parts_records
from heoslice.pipeline.printers import check_printer_materials, printer_grid
from heoslice.pipeline.runs import RunContext, RunResult
from heoslice.pipeline.spec import (
    MAX_COORDINATE_MM,
    SliceSpec,
    StageTimes,
    channel_name,
)
from heoslice.stack import (
    ChannelRecord,
    ImageRecord,
    LayerRecord,
    build_manifest,
    check_image_size,
    check_stack_output,
    droplet_summary,
    grading_summary,
    incomplete_stack,
    max_layer_count,
    prepare_directory,
    write_manifest,
)


def layer_limit(spec: SliceSpec) -> int:
    """Most layers a stack sliced with ``spec`` may have: :func:`heoslice.stack.max_layer_count` for its
    droplet-mask channels, so that a stack heoslice writes is one it can verify and print."""
    return max_layer_count([channel_name(m) for m in _droplet_materials(spec) or ()])


def _droplet_materials(spec: SliceSpec) -> tuple | None:
    """The droplet masks' materials in the order of the layers' masks (grading.materials'), or None for a
    stack without droplet masks."""
    if spec.parts is not None:
        return spec.parts.channel_materials() or None
    return spec.grade.channel_materials() if spec.channels else None


def slice_warnings(mesh: Mesh, spec: SliceSpec) -> list[str]:
    """What about this slice the user should know before it runs (one line each), e.g. a scan's many colours
    mapped onto few materials, or a layer height above the part's height, which makes one layer of the whole
    part."""
    collapse = colour_collapse(mesh, spec)
    warnings = [] if collapse is None else [collapse]
    z_min, z_max = (float(v) for v in mesh.bounds[:, 2])
    height, cut = z_max - z_min, z_min + spec.layer_height_mm / 2
    if spec.layer_height_mm <= height:
        return warnings
    outcome = "above the part: the stack is empty" if cut >= z_max else "through the part"
    return [*warnings, f"layer_height_mm: {spec.layer_height_mm:g} mm is more than the part's height ({height:g} "
            f"mm): the stack is one layer, cut at z = {cut:g} mm, {outcome}"]


def _check_sizes(mesh: Mesh, spec: SliceSpec) -> None:
    """Refuse a mesh whose coordinates are not finite or lie beyond MAX_COORDINATE_MM, before any size is
    derived from them."""
    largest = float(np.abs(mesh.bounds).max()) if np.all(np.isfinite(mesh.bounds)) else float("inf")
    if not largest <= MAX_COORDINATE_MM:
        raise InputError(f"{mesh.source.name}: coordinates reach {largest:g} mm from the origin, beyond the "
                         f"{MAX_COORDINATE_MM:g} mm a slice can hold")


def slice_to_stack(mesh: Mesh, directory: Path, spec: SliceSpec, *, force: bool = False,
                   progress: Callable[[int, int], None] | None = None,
                   scale: float = 1.0, inputs: tuple[Path, ...] | None = None) -> tuple[dict, StageTimes]:
    """Slice ``mesh`` into a stack in ``directory``; return the manifest and stage timings.

    ``scale``: the factor ``mesh``'s file coordinates were multiplied by (``--scale``), recorded in the
    manifest so that ``verify --mesh`` compares with the file as sliced. ``progress(done, total)`` is called
    as each layer is written. The manifest is written last; if anything fails before, the directory holds no
    manifest. ``inputs`` (default: the mesh's file) are never written over (the output rule,
    :func:`heoslice.stack.check_stack_output`).
    """
    directory = Path(directory)
    inputs = (mesh.source,) if inputs is None else inputs
    check_stack_output(directory, force, inputs)
    times = StageTimes()
    started = time.perf_counter()
    _check_sizes(mesh, spec)
    job = material_job(mesh, spec)
    spec = job.spec
    grid = grid_for(mesh.bounds[:, :2], spec.dpi, spec.margin_mm, spec.canvas_mm)
    check_printer_materials(spec.printer, len(_droplet_materials(spec) or ()))
    grid = printer_grid(grid, spec.printer)
    check_image_size(grid.width, grid.height)
    bounds = mesh.bounds
    limit = layer_limit(spec)
    if layer_count(bounds[0, 2], bounds[1, 2], spec.layer_height_mm, limit) > limit:
        raise InputError(f"layer_height_mm: {spec.layer_height_mm:g} mm gives more than {limit} layers for this "
                         f"part's {float(bounds[1, 2] - bounds[0, 2]):g} mm (the most one stack's manifest holds)")
    with ExitStack() as held:
        # held from before --force empties the directory to the manifest: a print holding the stack, or a
        # second slice into it, makes this one stop with one line (locks.StackBusyError) instead of racing
        existed = directory.is_dir()
        if existed:
            held.enter_context(hold_stack(directory, "slicing into it"))
        prepare_directory(directory, force, inputs)
        if not existed:
            held.enter_context(hold_stack(directory, "slicing into it"))
        held.enter_context(_incomplete_if_interrupted(directory))
        z = plane_heights(bounds[0, 2], bounds[1, 2], spec.layer_height_mm)
        results: dict[int, tuple] = {}
        open_layers = np.zeros(len(z), dtype=bool)

        def on_done(run: RunResult) -> None:
            for index, digest, solid, raster_s, encode_s, channels in run.layers:
                results[index] = (digest, solid, channels)
                times.raster += raster_s
                times.encode += encode_s
            open_layers[run.open_layers] = True
            times.slice += run.slice_s
            times.contours += run.contours_s

        written = [0]

        def on_layers(count: int) -> None:
            written[0] += count
            if progress is not None:
                progress(written[0], len(z))

        context = RunContext(mesh=mesh, z=z, face_range=face_z_range(mesh.vertices, mesh.faces), grid=grid,
                             spec=spec, directory=directory, vertex_mix=job.vertex_mix, field=job.field)
        run_all(context, spec.worker_count(), on_done, on_layers)
        mode = _image_mode(spec)
        droplets = _droplet_materials(spec)
        manifest = build_manifest(
            source_file=mesh.source.name, source_sha256=mesh.sha256, layer_height_mm=spec.layer_height_mm,
            dpi=spec.dpi, pixel_size_mm=(grid.px, grid.py),
            image=ImageRecord(grid.width, grid.height, (grid.x_left, grid.y_top), mode, spec.compression),
            z_range_mm=(bounds[0, 2], bounds[1, 2]), warnings=mesh.warnings, scale=scale,
            layers=[LayerRecord(z[index], results[index][0], results[index][1], open_layers[index],
                                None if droplets is None else _channel_records(droplets, results[index][2]))
                    for index in range(len(z))],
            grading=_grading(spec), parts=None if spec.parts is None else parts_records(
                mesh.parts, spec.parts, ranked_part_volumes_mm3(mesh, spec.parts.order)))
        write_manifest(directory, manifest)
        times.total = time.perf_counter() - started
        return manifest, times


@contextmanager
def _incomplete_if_interrupted(directory: Path):
    """An interruption (Ctrl-C, a terminating signal) of the block leaves ``directory`` without its manifest: it
    carries a note (PEP 678 ``__notes__``, which the CLI appends to its one line) saying so and what to run."""
    try:
        yield
    except KeyboardInterrupt as interrupt:
        interrupt.__notes__ = [*getattr(interrupt, "__notes__", ()), incomplete_stack(directory)]
        raise


def _image_mode(spec: SliceSpec) -> str:
    """The layer images' mode: RGBA for a graded preview stack (materials' colours), else 1-bit: the solid
    mask (with droplet masks, which carry the materials; a multi-part job's too)."""
    return "RGBA" if spec.parts is None and spec.grade is not None and not spec.channels else "1"


def _grading(spec: SliceSpec) -> dict | None:
    """The manifest's ``grading`` object: the grading's, a multi-part job's droplet masks', or None."""
    if spec.parts is not None:
        return droplet_summary(spec.parts.materials) if spec.parts.channels else None
    if spec.grade is None:
        return None
    return grading_summary(spec.grade, spec.halftone if spec.channels else None, interior=spec.interior,
                           design=None if spec.design is None else spec.design.record())


def _channel_records(materials: tuple, written: tuple) -> tuple[ChannelRecord, ...]:
    """The manifest records of one layer's droplet masks: material, file, sha256, solid pixels."""
    return tuple(ChannelRecord(material.name, name, digest, solid)
                 for material, (name, digest, solid) in zip(materials, written))
