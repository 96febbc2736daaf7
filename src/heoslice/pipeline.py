"""The slice pipeline: mesh -> sections -> contours -> layer images -> stack on disk.

This module only connects the stages (:mod:`slicing`, :mod:`contours`,
:mod:`rasterising`, :mod:`stack`); it renders and encodes layers in parallel
worker processes, streaming each to disk as soon as it is done so that memory
does not grow with the number of layers.
"""

from __future__ import annotations

import ctypes
import gc
import mmap
import os
import signal
import time
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from contextlib import contextmanager
from dataclasses import dataclass, field, fields, replace
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from heoslice.contours import Contours, build_contours
from heoslice.errors import InputError
from heoslice.loading import Mesh
from heoslice.rasterising import Grid, count_solid, grid_for, packed_mask, render_layer
from heoslice.regions import GradeSpec, droplet_planes, render_graded
from heoslice.slicing import face_z_range, interpolate_at, plane_chunks, plane_heights, slice_planes
from heoslice.stack import (
    COMPRESSIONS,
    DEFAULT_COMPRESSION,
    ChannelRecord,
    ImageRecord,
    LayerRecord,
    build_manifest,
    check_image_size,
    grading_summary,
    encode_bilevel_tiff,
    encode_tiff,
    layer_file_name,
    max_layer_count,
    prepare_directory,
    write_file,
    write_manifest,
)


MIN_LAYER_MM = 1e-3
MIN_DPI, MAX_DPI = 1.0, 100_000.0


@dataclass(frozen=True)
class SliceSpec:
    """What to slice and how: layer height (mm), resolution (dpi x, y), canvas, encoding, workers.

    ``grade`` asks for graded interiors (:mod:`heoslice.regions`), ``channels`` for one
    droplet mask per material per layer (:mod:`heoslice.halftone`; needs ``grade``).
    """

    layer_height_mm: float = 0.1
    dpi: tuple[float, float] = (600.0, 600.0)
    margin_mm: float = 1.0
    canvas_mm: tuple[float, float] | None = None
    compression: str = DEFAULT_COMPRESSION
    jobs: int = 0
    base_color: tuple[int, int, int] = (255, 255, 255)
    grade: GradeSpec | None = None
    channels: bool = False
    #: Segments sliced and chained at once; bounds memory (a few hundred bytes per segment).
    max_segments: int = 50_000

    def __post_init__(self):
        if self.compression not in COMPRESSIONS:
            raise InputError(f"--compress: unknown compression {self.compression!r}; "
                             f"choose one of {', '.join(COMPRESSIONS)}")
        if not (np.isfinite(self.layer_height_mm) and self.layer_height_mm >= MIN_LAYER_MM):
            raise InputError(f"--layer: layer height must be a number of at least {MIN_LAYER_MM} mm, "
                             f"got {self.layer_height_mm}")
        if not (np.isfinite(self.margin_mm) and self.margin_mm >= 0):
            raise InputError(f"--margin: must be a finite number >= 0, got {self.margin_mm}")
        if not all(np.isfinite(d) and MIN_DPI <= d <= MAX_DPI for d in self.dpi):
            raise InputError(f"--dpi: each resolution must be between {MIN_DPI} and {MAX_DPI}, got {self.dpi}")
        if self.canvas_mm is not None and not all(np.isfinite(v) and v > 0 for v in self.canvas_mm):
            raise InputError(f"--canvas: width and height must be finite and positive, got {self.canvas_mm}")
        if self.jobs < 0:
            raise InputError(f"--jobs: must be 0 (all cores) or more, got {self.jobs}")
        if self.channels and self.grade is None:
            raise InputError("--channels needs a graded slice (--grade)")
        if self.grade is not None:
            names = [channel_name(material) for material in self.grade.channel_materials()]
            if len(set(names)) != len(names):
                raise InputError(f"--materials: material names give the same droplet-mask file names ({names}); "
                                 "rename them")

    def worker_count(self) -> int:
        return self.jobs if self.jobs > 0 else max(1, len(os.sched_getaffinity(0)))


@dataclass
class StageTimes:
    """Seconds spent per stage, summed over the runs of planes and the worker processes (CPU seconds)."""

    slice: float = 0.0
    contours: float = 0.0
    raster: float = 0.0
    encode: float = 0.0
    total: float = 0.0


@dataclass(frozen=True)
class LayerJob:
    """Everything a worker needs to render and write one layer."""

    index: int
    points: np.ndarray
    offsets: np.ndarray
    point_colors: np.ndarray | None
    grid: Grid
    dpi: tuple[float, float]
    compression: str
    layer_height_mm: float
    base_color: tuple[int, int, int]
    path: Path
    graded: "GradedJob | None" = None
    #: The layer's solid bits when a helper made them ahead (:func:`packed_mask`'s).
    packed: np.ndarray | None = None


@dataclass(frozen=True)
class GradedJob:
    """The extra a graded layer needs: its loops' signed areas, parents and shells ((l,), within
    the layer), the contour points' material fractions ((p,) or None), and the channel files."""

    spec: GradeSpec
    area: np.ndarray
    parent: np.ndarray
    loop_shell: np.ndarray | None
    point_material: np.ndarray | None
    channel_paths: tuple[Path, ...] | None


def render_and_write(job: LayerJob, reuse: dict | None = None) -> tuple:
    """Render, encode and write one layer.

    Returns (index, sha256, solid pixels, raster s, encode s, channel entries); the
    channel entries (graded layers with droplet masks) are (file name, sha256, solid pixels).
    A graded layer takes the sub-regions of families it shares with the layer rendered
    before it with the same ``reuse`` dict (:func:`heoslice.regions.layer_regions`); a 1-bit
    layer with the same solid bits as that one takes its encoded TIFF.
    """
    if job.graded is not None:
        return _render_graded_and_write(job, reuse)
    started = time.perf_counter()
    image, solid = render_layer(job.points, job.offsets, job.grid, point_colors=job.point_colors,
                                base_color=job.base_color)
    rendered = time.perf_counter()
    if job.point_colors is None:
        data = _solid_tiff(image, solid, job, reuse)
    else:
        data = encode_tiff(image, job.dpi, job.compression, job.layer_height_mm)
    encoded = time.perf_counter()
    digest = write_file(job.path, data)
    return job.index, digest, solid, rendered - started, encoded - rendered, ()


def _solid_tiff(packed: np.ndarray, solid: int, job: LayerJob, reuse: dict | None) -> bytes:
    """The 1-bit TIFF of a layer's solid bits ((h, ceil(w / 8)) uint8, ``solid`` of them set): the last
    layer's (kept in ``reuse``) when the bits are the same, as an extruded part's layers are (the bits are
    compared only when their counts are equal)."""
    form = (job.grid.width, job.dpi, job.compression, solid)
    last = None if reuse is None else reuse.get("solid_tiff")
    if last is not None and last[0] == form and np.array_equal(last[1], packed):
        return last[2]
    data = encode_bilevel_tiff(packed, job.grid.width, job.dpi, job.compression, job.layer_height_mm)
    if reuse is not None:
        reuse["solid_tiff"] = (form, packed, data)
    return data


def _render_graded_and_write(job: LayerJob, reuse: dict | None) -> tuple:
    """The graded branch of :func:`render_and_write`: the RGBA layer, or with droplet masks the
    1-bit solid layer plus one 1-bit TIFF per material."""
    graded = job.graded
    started = time.perf_counter()
    packed = job.packed if job.packed is not None else packed_mask(job.points, job.offsets, job.grid)
    if graded.channel_paths is not None:
        planes = droplet_planes(job.points, job.offsets, graded.area, graded.parent, graded.loop_shell, None,
                                job.grid, graded.spec, job.index, point_material=graded.point_material,
                                packed=packed, reuse=reuse)
        rendered = time.perf_counter()
        width = job.grid.width
        solid = count_solid(packed)
        data = _solid_tiff(packed, solid, job, reuse)
        pieces = [(path, encode_bilevel_tiff(plane, width, job.dpi, job.compression, job.layer_height_mm), count_solid(plane))
                  for path, plane in zip(graded.channel_paths, planes)]
        encoded = time.perf_counter()
        digest = write_file(job.path, data)
        channels = tuple((path.name, write_file(path, blob), count) for path, blob, count in pieces)
        return job.index, digest, solid, rendered - started, encoded - rendered, channels
    mask = np.unpackbits(packed, axis=1, count=job.grid.width).view(bool)
    layer = render_graded(job.points, job.offsets, graded.area, graded.parent, graded.loop_shell, mask, job.grid,
                          graded.spec, job.index, point_colors=job.point_colors,
                          point_material=graded.point_material, reuse=reuse)
    rendered = time.perf_counter()
    data = encode_tiff(layer.image, job.dpi, job.compression, job.layer_height_mm)
    encoded = time.perf_counter()
    digest = write_file(job.path, data)
    return job.index, digest, layer.solid, rendered - started, encoded - rendered, ()


def layer_jobs(contours: Contours, mesh: Mesh, grid: Grid, spec: SliceSpec, directory: Path,
               first_layer: int = 0):
    """One LayerJob per layer of ``contours`` (layer k is stack layer first_layer + k), built lazily."""
    colors = None if mesh.colors is None else mesh.colors.astype(np.float64)
    grade = spec.grade
    materials = grade.channel_materials() if grade is not None else ()
    loop_shell = None if grade is None or mesh.shell is None or not len(contours.face) else mesh.shell[contours.face]
    for local in range(len(contours.layer_offsets) - 1):
        index = first_layer + local
        first, last = contours.layer_offsets[local], contours.layer_offsets[local + 1]
        start, stop = contours.offsets[first], contours.offsets[last]
        point_colors = None
        if colors is not None:
            point_colors = interpolate_at(colors, contours.point_edge[start:stop], contours.point_t[start:stop])
        graded = None
        if grade is not None:
            parent = contours.parent[first:last]
            point_material = None
            if mesh.material is not None:
                point_material = interpolate_at(mesh.material, contours.point_edge[start:stop],
                                                contours.point_t[start:stop])
            graded = GradedJob(
                spec=grade,
                area=contours.area[first:last],
                parent=np.where(parent >= 0, parent - first, -1),
                loop_shell=None if loop_shell is None else loop_shell[first:last],
                point_material=point_material,
                channel_paths=tuple(directory / layer_file_name(index, channel_name(m)) for m in materials)
                if spec.channels else None,
            )
        yield LayerJob(
            index=index,
            points=contours.points[start:stop],
            offsets=contours.offsets[first:last + 1] - start,
            point_colors=point_colors,
            grid=grid,
            dpi=spec.dpi,
            compression=spec.compression,
            layer_height_mm=spec.layer_height_mm,
            base_color=spec.base_color,
            path=directory / layer_file_name(index),
            graded=graded,
        )


def channel_name(material) -> str:
    """The file-name suffix of a material's droplet masks: its name with anything but letters,
    digits and '-' replaced by '-' (e.g. '0,255,0' -> '0-255-0')."""
    import re

    return re.sub(r"[^A-Za-z0-9-]", "-", str(material.name)) or "material"


@dataclass(frozen=True)
class RunContext:
    """What every run of planes needs: the mesh, the planes and how to render and write them.

    Worker processes receive it once, by fork inheritance through the pool's
    initializer (never pickled), and then only (start, stop) plane indices per task.
    """

    mesh: Mesh
    z: np.ndarray
    face_range: tuple[np.ndarray, np.ndarray]
    grid: Grid
    spec: SliceSpec
    directory: Path
    #: Runs already sliced and chained (by :func:`_slice_ahead`): (start, stop) -> (contours, slice s, chain s),
    #: and the solid bits of some of their layers: (start, stop) -> (layers, h, ceil(w / 8)) uint8.
    ahead: dict = field(default_factory=dict)
    ahead_masks: dict = field(default_factory=dict)


@dataclass(frozen=True)
class RunResult:
    """One run's layers (render_and_write results), its open-contour layers and stage seconds."""

    layers: list
    open_layers: np.ndarray
    slice_s: float
    contours_s: float


#: The RunContext of this worker process and what the last layer it rendered leaves to the next (``reuse``
#: of :func:`slice_run`), set by :func:`_adopt` (each worker has its own).
_WORKER_CONTEXT: dict = {}


def _adopt(context: RunContext, reuse: dict) -> None:
    """Worker initializer: keep the context and what the parent's first layer left to the next (``reuse``,
    this worker's copy by fork); Ctrl-C is the parent's to handle (one 'interrupted' line)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    keep_freed_memory()
    _WORKER_CONTEXT["run"] = context
    _WORKER_CONTEXT["reuse"] = reuse


#: glibc's mallopt parameters (malloc.h) and the values a worker sets: blocks below 32 MB (glibc's largest
#: M_MMAP_THRESHOLD on 64 bits) come from the heap, and freed heap memory stays in the process.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
_KEPT_BYTES, _HEAP_BLOCK_BYTES = 2**31 - 1, 32 << 20  # mallopt takes a C int


def keep_freed_memory() -> bool:
    """Let this process's C allocator keep the memory numpy frees, for the next layer; True if it could.

    Every layer allocates and frees the same few-MB arrays; glibc otherwise maps them afresh or
    gives them back to the kernel, and each comes back as newly zeroed pages (~170 k page faults, a
    third of a second of system time, on the benchmark's part with holes). What is kept is what the
    worker had used (peak RSS measured: organ 54 -> 55 MB, graded holes 213 -> 222 MB; a heap this
    large can hold fragments). Called in worker processes only (a library caller's own process keeps
    its settings); a no-op where the C library has no mallopt (not glibc).
    """
    mallopt = getattr(ctypes.CDLL(None), "mallopt", None)
    if mallopt is None:
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    done = [mallopt(_M_MMAP_THRESHOLD, _HEAP_BLOCK_BYTES), mallopt(_M_TRIM_THRESHOLD, _KEPT_BYTES)]
    return all(done)


def slice_run(context: RunContext, start: int, stop: int, reuse: dict | None = None) -> RunResult:
    """Slice, chain, render and write planes z[start:stop]: the whole pipeline for one run of layers.

    ``reuse`` keeps what the last layer rendered leaves to the next when they are alike (an extruded
    part): its sub-regions, choice table and encoded 1-bit TIFF (:func:`render_and_write`); a dict kept
    from run to run (same context) carries them over to the next run's first layer too."""
    contours, slice_s, contours_s = run_contours(context, start, stop)
    jobs = layer_jobs(contours, context.mesh, context.grid, context.spec, context.directory, first_layer=start)
    masks = context.ahead_masks.get((start, stop))
    if masks is not None:
        jobs = (replace(job, packed=mask) for job, mask in zip(jobs, masks))
    reuse = {} if reuse is None else reuse
    return RunResult(layers=[render_and_write(job, reuse) for job in jobs],
                     open_layers=start + contours.layer[contours.closed_by_join],
                     slice_s=slice_s, contours_s=contours_s)


def run_contours(context: RunContext, start: int, stop: int) -> tuple[Contours, float, float]:
    """The contours of planes z[start:stop] (numpy only, no compiled kernel), with the seconds spent slicing
    and chaining them: from ``context.ahead`` when a helper made them already."""
    made = context.ahead.get((start, stop))
    if made is not None:
        return made
    mesh = context.mesh
    began = time.perf_counter()
    sections = slice_planes(mesh.vertices, mesh.faces, context.z, start, stop, context.face_range)
    sliced = time.perf_counter()
    contours = build_contours(sections, hierarchy=context.spec.grade is not None)
    return contours, sliced - began, time.perf_counter() - sliced


def _slice_run_in_worker(start: int, stop: int) -> RunResult:
    return slice_run(_WORKER_CONTEXT["run"], start, stop, _WORKER_CONTEXT["reuse"])


def plane_runs(context: RunContext, max_layers: int = 32) -> list[tuple[int, int]]:
    """Runs of at most ``spec.max_segments`` segments and ``max_layers`` planes (memory and load balance)."""
    runs = []
    for start, stop in plane_chunks(context.mesh.vertices, context.mesh.faces, context.z,
                                    context.spec.max_segments, context.face_range):
        runs += [(first, min(first + max_layers, stop)) for first in range(start, stop, max_layers)]
    return runs


#: Most bytes a helper makes ahead (shared memory, touched only as written), and of them at most
#: AHEAD_MASK_BYTES of solid masks (a 15 MP organ's run of masks is 32 MB: each worker maps what it reads).
AHEAD_BYTES = 256 << 20
AHEAD_MASK_BYTES = 64 << 20
#: Longest wait (s) for a helper to answer, and then to end, before it is left aside (and killed).
_AHEAD_WAIT_S = 10.0


@contextmanager
def _sliced_ahead(context: RunContext, runs: list[tuple[int, int]]):
    """Fork a helper that slices and chains ``runs`` in order, then makes their layers' solid bits
    (:func:`_slice_ahead`), while the body runs; yields ``collect()``, which stops it and returns
    ``context`` with what it finished (``ahead``, ``ahead_masks``): read-only views of the memory it shares
    with this process (and with the workers forked after). What a helper that fails or does not answer in
    _AHEAD_WAIT_S did not finish, the workers make."""
    if not runs:
        yield lambda: context
        return
    buffer = mmap.mmap(-1, AHEAD_BYTES)
    fork = get_context("fork")
    ours, theirs = fork.Pipe()
    helper = fork.Process(target=_slice_ahead, args=(context, runs, buffer, theirs, ours), daemon=True)
    # Ctrl-C held back over the fork: the helper ignores it before it can arrive (the parent handles it)
    held = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        helper.start()
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, held)
    theirs.close()

    def collect() -> RunContext:
        try:
            ours.send(None)
            if not ours.poll(_AHEAD_WAIT_S):
                return context
            placed, masks = ours.recv()
        except (OSError, EOFError):
            return context
        return replace(context, ahead={run: (_shared_contours(buffer, layout), *seconds)
                                       for run, layout, seconds in placed},
                       ahead_masks={run: _shared_array(buffer, where) for run, where in masks})

    try:
        yield collect
    finally:
        ours.close()
        helper.join(timeout=_AHEAD_WAIT_S)
        if helper.is_alive():
            helper.kill()
            helper.join()


def _slice_ahead(context: RunContext, runs: list[tuple[int, int]], buffer: mmap.mmap, conn, parent_end=None
                 ) -> None:
    """Helper process: :func:`run_contours` of ``runs`` in order, then the solid bits of their layers run by
    run, each copied into ``buffer``, until the parent asks (anything on ``conn``, or its end closed) or the
    buffer is full; then send where each run's contours and masks lie. ``parent_end``, the parent's end of the
    pipe as forked into this process, is closed first, so that the parent closing its own is seen here."""
    if parent_end is not None:
        parent_end.close()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    placed, masks, used, mask_bytes = [], [], 0, 0
    try:
        for run in runs:
            if conn.poll():
                break
            contours, *seconds = run_contours(context, *run)
            layout = []
            for item in fields(Contours):
                where, used = _copy_array(getattr(contours, item.name), buffer, used)
                layout.append((item.name, where))
            if used > len(buffer):
                break
            placed.append((run, layout, seconds))
        for run, layout, _ in placed:
            if conn.poll():
                break
            jobs = list(layer_jobs(_shared_contours(buffer, layout), context.mesh, context.grid, context.spec,
                                   context.directory, first_layer=run[0]))
            grid = context.grid
            shape = (len(jobs), grid.height, -(-grid.width // 8))
            mask_bytes += int(np.prod(shape))
            where, used = _place(shape, np.uint8, used)
            if used > len(buffer) or mask_bytes > AHEAD_MASK_BYTES:
                break
            bits = _shared_array(buffer, where, writeable=True)
            for layer, job in enumerate(jobs):
                bits[layer] = packed_mask(job.points, job.offsets, grid)
            masks.append((run, where))
    except Exception:  # noqa: BLE001 - what is not made here the workers make, and they report its errors
        pass
    try:
        conn.recv()
        conn.send((placed, masks))
    except (EOFError, OSError):
        pass  # the parent stopped before it asked (an error, Ctrl-C): nothing is wanted


def _place(shape: tuple, dtype, used: int) -> tuple[tuple, int]:
    """Where an array of ``shape`` and ``dtype`` goes in a shared buffer whose first ``used`` bytes are taken,
    64-byte aligned: ((dtype, shape, offset), bytes taken after)."""
    dtype = np.dtype(dtype)
    start = -(-used // 64) * 64
    return (dtype.str, tuple(shape), start), start + dtype.itemsize * int(np.prod(shape))


def _copy_array(array: np.ndarray | None, buffer: mmap.mmap, used: int) -> tuple[tuple | None, int]:
    """Copy ``array`` into ``buffer`` after its first ``used`` bytes (:func:`_place`): (where, bytes taken after;
    None and ``used`` for no array). Nothing is copied past the end (the bytes taken then exceed the length)."""
    if array is None:
        return None, used
    where, used = _place(array.shape, array.dtype, used)
    if used <= len(buffer):
        _shared_array(buffer, where, writeable=True)[...] = array
    return where, used


def _shared_array(buffer: mmap.mmap, where: tuple | None, writeable: bool = False) -> np.ndarray | None:
    """A view (read-only unless ``writeable``) of an array placed in ``buffer`` (:func:`_place`)."""
    if where is None:
        return None
    dtype, shape, offset = where
    array = np.ndarray(shape, np.dtype(dtype), buffer=buffer, offset=offset)
    array.flags.writeable = writeable
    return array


def _shared_contours(buffer: mmap.mmap, layout: list) -> Contours:
    """The Contours whose arrays :func:`_slice_ahead` placed in ``buffer`` (layout: (field, where) per field)."""
    return Contours(**{name: _shared_array(buffer, where) for name, where in layout})


def _run_all(context: RunContext, workers: int, on_done: Callable[[RunResult], None]) -> None:
    """Every run of planes through :func:`slice_run`: in this process, or (but for the first layer, rendered
    here) in ``workers`` forked processes with at most 2 runs each in flight (results arrive in any order;
    memory stays bounded)."""
    runs = plane_runs(context)
    if workers <= 1:
        reuse: dict = {}
        for start, stop in runs:
            on_done(slice_run(context, start, stop, reuse))
        return
    # The first layer is rendered here, before the workers are forked: what it loads (compiled kernels and
    # their registries, codecs) is loaded once and inherited, not by every worker side by side (two took
    # 1.03 s at once against 0.85 s for one, graded holes part). Meanwhile, when that takes long (graded
    # layers), a helper slices and chains the next runs on the core that would idle. Frozen before each
    # fork, as Python's gc documentation advises, the objects made so far stay out of the collections (whose
    # writes would copy the pages this process shares with the helper and the workers).
    start, stop = runs[0]
    runs = ([(start + 1, stop)] if stop > start + 1 else []) + runs[1:]
    first: dict = {}
    freeze = gc.freeze if gc.get_freeze_count() == 0 else lambda: None  # a caller's own freezing is left alone
    freeze()
    try:
        with _sliced_ahead(context, runs if context.spec.grade is not None else []) as collect:
            on_done(slice_run(context, start, start + 1, first))
            context = collect()
        if not runs:
            return
        freeze()
        with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("fork"),
                                 initializer=_adopt, initargs=(context, first)) as pool:
            pending = set()
            for start, stop in runs:
                pending.add(pool.submit(_slice_run_in_worker, start, stop))
                if len(pending) >= 2 * workers:
                    done, pending = wait(pending, return_when=FIRST_COMPLETED)
                    for future in done:
                        on_done(future.result())
            for future in pending:
                on_done(future.result())
    finally:
        if freeze is gc.freeze:
            gc.unfreeze()


def slice_to_stack(mesh: Mesh, directory: Path, spec: SliceSpec, *, force: bool = False,
                   progress: Callable[[int, int], None] | None = None) -> tuple[dict, StageTimes]:
    """Slice ``mesh`` into a stack in ``directory``; return the manifest and stage timings.

    ``progress(done, total)`` is called as layers finish. The manifest is written
    last; if anything fails before, the directory holds no manifest.
    """
    directory = Path(directory)
    times = StageTimes()
    started = time.perf_counter()
    grid = grid_for(mesh.bounds[:, :2], spec.dpi, spec.margin_mm, spec.canvas_mm)
    check_image_size(grid.width, grid.height)
    bounds = mesh.bounds
    layers = int(np.ceil((bounds[1, 2] - bounds[0, 2]) / spec.layer_height_mm))
    most = max_layer_count([m.name for m in spec.grade.channel_materials()] if spec.channels else ())
    if layers > most:
        raise InputError(f"--layer {spec.layer_height_mm} mm gives {layers} layers for this part "
                         f"(a stack holds at most {most}{' with these droplet masks' if spec.channels else ''})")
    prepare_directory(directory, force)
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
        if progress is not None:
            progress(len(results), len(z))

    context = RunContext(mesh=mesh, z=z, face_range=face_z_range(mesh.vertices, mesh.faces), grid=grid,
                         spec=spec, directory=directory)
    _run_all(context, spec.worker_count(), on_done)
    mode = _image_mode(mesh, spec)
    manifest = build_manifest(
        source_file=mesh.source.name, source_sha256=mesh.sha256, layer_height_mm=spec.layer_height_mm,
        dpi=spec.dpi, pixel_size_mm=(grid.px, grid.py),
        image=ImageRecord(grid.width, grid.height, (grid.x_left, grid.y_top), mode, spec.compression),
        z_range_mm=(bounds[0, 2], bounds[1, 2]), warnings=mesh.warnings,
        layers=[LayerRecord(z[index], results[index][0], results[index][1], open_layers[index],
                            _channel_records(spec.grade, results[index][2]) if spec.channels else None)
                for index in range(len(z))],
        grading=None if spec.grade is None else grading_summary(spec.grade))
    write_manifest(directory, manifest)
    times.total = time.perf_counter() - started
    return manifest, times


def _image_mode(mesh: Mesh, spec: SliceSpec) -> str:
    """The layer images' mode: RGBA for colours (a coloured mesh, graded interiors), except that
    with droplet masks the layer image is the 1-bit solid mask and the masks carry the materials."""
    return "RGBA" if (mesh.colors is not None or spec.grade is not None) and not spec.channels else "1"


def _channel_records(grade: GradeSpec, written: tuple) -> tuple[ChannelRecord, ...]:
    """The manifest records of one layer's droplet masks: material, file, sha256, solid pixels."""
    return tuple(ChannelRecord(material.name, name, digest, solid)
                 for material, (name, digest, solid) in zip(grade.channel_materials(), written))
