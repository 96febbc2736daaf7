"""One layer's job: what it needs (:class:`LayerJob`), how it is rendered, encoded and written, and what
one layer leaves to the next that the same process renders (:class:`PipelineCache`)."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from heoslice.layers.contours import Contours
from heoslice.layers.rasterising import Grid, packed_mask_and_count, part_rows, render_layer
from heoslice.layers.slicing import interpolate_at
from heoslice.mesh import Mesh
from heoslice.pipeline.spec import SliceSpec, channel_name
from heoslice.stack import encode_bilevel_tiff, encode_tiff, layer_file_name, write_file
from heoslice.stack.tiff import deflate_level, mask_deflation

if TYPE_CHECKING:  # the grading package loads its kernels and shapely: a one-material slice never imports it
    from heoslice.grading import GradeSpec, GradingCache
    from heoslice.grading.diffusion import DiffusionCarry


@dataclass(frozen=True, slots=True)
class EncodedSolid:
    """A 1-bit layer as encoded: its form (width, dpi, compression, solid pixels), its packed solid bits
    ((h, ceil(w / 8)) uint8) and its TIFF bytes."""

    form: tuple
    packed: np.ndarray
    data: bytes


@dataclass(slots=True)
class PipelineCache:
    """What the last layer a process rendered leaves to the next when they are alike (an extruded part).

    ``grading`` is the grading stage's own cache (sub-regions, rings, choice table), handed to it
    unchanged; ``solid`` the last 1-bit layer's encoding. One cache per process, kept from run to run
    (the same slice); a worker starts from a copy of the one its parent's first layer filled. ``carry`` is
    not a cache but state: the error an error-diffusion halftone leaves to the next layer
    (:class:`heoslice.grading.diffusion.DiffusionCarry`), dropped where a run of planes starts
    (:func:`heoslice.pipeline.runs.slice_run`).
    """

    grading: GradingCache | None = None
    solid: EncodedSolid | None = None
    carry: DiffusionCarry | None = None


@dataclass(frozen=True)
class GradedJob:
    """The extra a graded layer needs: its loops' signed areas, parents and shells ((l,), within
    the layer), the contour points' material mixes ((p, K) float over the channel materials, or None),
    and the channel files, and the halftoning method of the droplet masks; for the ``field`` interior, the
    design's field (:class:`heoslice.material.field.MaterialField`) and the layer's height z (mm)."""

    spec: GradeSpec
    area: np.ndarray
    parent: np.ndarray
    loop_shell: np.ndarray | None
    point_material: np.ndarray | None
    channel_paths: tuple[Path, ...] | None
    field: object | None = None
    z: float = 0.0
    halftone: str = "ordered"


@dataclass(frozen=True)
class LayerJob:
    """Everything needed to render and write one layer: its loops ((p, 2) float points, mm, and
    (loops + 1,) offsets), the grid and encoding, the file, and what grading it needs."""

    index: int
    points: np.ndarray
    offsets: np.ndarray
    grid: Grid
    dpi: tuple[float, float]
    compression: str
    layer_height_mm: float
    path: Path
    graded: GradedJob | None = None


def render_and_write(job: LayerJob, cache: PipelineCache | None = None) -> tuple:
    """Render, encode and write one layer.

    Returns (index, sha256, solid pixels, raster s, encode s, channel entries); the
    channel entries (graded layers with droplet masks) are (file name, sha256, solid pixels).
    With a ``cache``, a graded layer takes the sub-regions of families it shares with the layer
    rendered before it (:func:`heoslice.grading.layer_regions`), and a 1-bit layer with the same
    solid bits as that one takes its encoded TIFF.
    """
    if job.graded is not None:
        return _render_graded_and_write(job, cache)
    started = time.perf_counter()
    packed, solid = render_layer(job.points, job.offsets, job.grid)
    rendered = time.perf_counter()
    data = _solid_tiff(packed, solid, job, cache, deflate_level(False), part_rows(job.points, job.grid))
    encoded = time.perf_counter()
    digest = write_file(job.path, data)
    return job.index, digest, solid, rendered - started, encoded - rendered, ()


def _solid_tiff(packed: np.ndarray, solid: int, job: LayerJob, cache: PipelineCache | None,
                level: int, rows: tuple[int, int] | None = None) -> bytes:
    """The 1-bit TIFF of a layer's solid bits ((h, ceil(w / 8)) uint8, ``solid`` of them set) at deflate
    ``level``, ``rows`` the part's (:func:`encode_bilevel_tiff`): the last layer's (kept in ``cache``) when
    the bits are the same, as an extruded part's layers are (the bits are compared only when their counts
    are equal)."""
    form = (job.grid.width, job.dpi, job.compression, level, solid)
    last = None if cache is None else cache.solid
    if last is not None and last.form == form and np.array_equal(last.packed, packed):
        return last.data
    data = encode_bilevel_tiff(packed, job.grid.width, job.dpi, job.compression, job.layer_height_mm, level=level,
                               rows=rows)
    if cache is not None:
        cache.solid = EncodedSolid(form, packed, data)
    return data


def _render_graded_and_write(job: LayerJob, cache: PipelineCache | None) -> tuple:
    """The graded branch of :func:`render_and_write`: the RGBA layer, or with droplet masks the
    1-bit solid layer plus one 1-bit TIFF per material."""
    graded = job.graded
    from heoslice.grading import (  # loaded by graded slices only
        GradingCache,
        droplet_planes,
        render_graded,
    )

    if cache is not None and cache.grading is None:
        cache.grading = GradingCache()
    grading_cache = None if cache is None else cache.grading
    if cache is not None and cache.carry is None and graded.halftone == "error-diffusion":
        from heoslice.grading.diffusion import DiffusionCarry

        cache.carry = DiffusionCarry()
    started = time.perf_counter()
    packed, solid = packed_mask_and_count(job.points, job.offsets, job.grid)
    if graded.field is not None:
        return _render_field_and_write(job, packed, solid, cache, started)
    if graded.channel_paths is not None:
        planes = droplet_planes(job.points, job.offsets, graded.area, graded.parent, graded.loop_shell, None,
                                job.grid, graded.spec, job.index, point_material=graded.point_material,
                                packed=packed, cache=grading_cache, method=graded.halftone,
                                carry=None if cache is None else cache.carry)
        return _write_masks(job, packed, solid, planes, cache, started)
    mask = np.unpackbits(packed, axis=1, count=job.grid.width).view(bool)
    layer = render_graded(job.points, job.offsets, graded.area, graded.parent, graded.loop_shell, mask, job.grid,
                          graded.spec, job.index,
                          point_material=graded.point_material, cache=grading_cache)
    rendered = time.perf_counter()
    data = encode_tiff(layer.image, job.dpi, job.compression, job.layer_height_mm)
    encoded = time.perf_counter()
    digest = write_file(job.path, data)
    return job.index, digest, layer.solid, rendered - started, encoded - rendered, ()


def _write_masks(job: LayerJob, packed: np.ndarray, solid: int, planes: np.ndarray, cache: PipelineCache | None,
                 started: float) -> tuple:
    """Encode and write a layer's 1-bit solid mask (``packed``) and its droplet masks (``planes``, (K, h,
    ceil(w / 8)) uint8, one per ``job.graded.channel_paths``; deflated as the halftone that made them says,
    :func:`heoslice.stack.tiff.mask_deflation`); the layer's result tuple, its render time measured from
    ``started``."""
    from heoslice.grading import droplet_counts

    rendered = time.perf_counter()
    width, rows = job.grid.width, part_rows(job.points, job.grid)
    data = _solid_tiff(packed, solid, job, cache, deflate_level(True), rows)
    encoder, level = mask_deflation(job.graded.halftone)
    pieces = [(path, encode_bilevel_tiff(plane, width, job.dpi, job.compression, job.layer_height_mm,
                                         level=level, rows=rows, encoder=encoder), count)
              for path, plane, count in zip(job.graded.channel_paths, planes, droplet_counts(planes, solid))]
    encoded = time.perf_counter()
    digest = write_file(job.path, data)
    channels = tuple((path.name, write_file(path, blob), count) for path, blob, count in pieces)
    return job.index, digest, solid, rendered - started, encoded - rendered, channels


def _render_field_and_write(job: LayerJob, packed: np.ndarray, solid: int, cache: PipelineCache | None,
                            started: float) -> tuple:
    """The ``field`` interior's branch of :func:`render_and_write`: each solid pixel's share of the design's target,
    f(r) at the pixel centre's own 3-D r (:class:`heoslice.material.field.MaterialField`), as droplet masks beside
    the 1-bit solid layer (:func:`heoslice.grading.pixel_mix.fraction_planes`; by a threshold tile, ordered or blue
    noise, each pixel's dither level read from the table of f's levels at r's step,
    :func:`heoslice.grading.pixel_mix.field_planes`), or as an RGBA preview layer."""
    from heoslice.grading.halftone import THRESHOLD_METHODS
    from heoslice.grading.pixel_mix import field_planes, fraction_colors, fraction_planes

    graded = job.graded
    grade, design = graded.spec, graded.field.design
    if graded.channel_paths is not None and graded.halftone in THRESHOLD_METHODS:
        planes = field_planes(graded.field, packed, job.grid, graded.z, job.index, grade.channel_index(design.start),
                              grade.channel_index(design.target), len(grade.channel_materials()), graded.halftone)
        return _write_masks(job, packed, solid, planes, cache, started)
    box, f = graded.field.layer_fraction(packed, job.grid, graded.z)
    if graded.channel_paths is not None:
        planes = fraction_planes(packed, box, f, job.grid, job.index, grade.channel_index(design.start),
                                 grade.channel_index(design.target), len(grade.channel_materials()),
                                 method=graded.halftone, carry=None if cache is None else cache.carry)
        return _write_masks(job, packed, solid, planes, cache, started)
    image = np.zeros((job.grid.height, job.grid.width, 4), dtype=np.uint8)
    r0, r1, c0, c1 = box
    rows, cols = np.nonzero(np.unpackbits(packed[r0:r1], axis=1, count=job.grid.width)[:, c0:c1])
    colors = fraction_colors(np.broadcast_to(f, (r1 - r0, c1 - c0))[rows, cols], design.start.color,
                             design.target.color)
    image[rows + r0, cols + c0, :3] = np.clip(np.rint(colors), 0, 255)
    image[rows + r0, cols + c0, 3] = 255
    rendered = time.perf_counter()
    data = encode_tiff(image, job.dpi, job.compression, job.layer_height_mm)
    encoded = time.perf_counter()
    return job.index, write_file(job.path, data), solid, rendered - started, encoded - rendered, ()


def layer_jobs(contours: Contours, mesh: Mesh, grid: Grid, spec: SliceSpec, directory: Path,
               first_layer: int = 0, vertex_mix: np.ndarray | None = None, field=None,
               z: np.ndarray | None = None):
    """One LayerJob per layer of ``contours`` (layer k is stack layer first_layer + k), built lazily.

    A graded layer's contour points carry ``vertex_mix`` ((n, K) float,
    :class:`heoslice.pipeline.materials.MaterialJob`) interpolated along their edges; its colours come from
    the materials, never from the mesh's own colours (which :func:`material_job` mapped to materials). With a
    ``field`` (the ``field`` interior) each layer is evaluated at its plane's height z[index] ((L,) mm).
    """
    grade = spec.grade
    materials = grade.channel_materials() if grade is not None else ()
    loop_shell = None if grade is None or mesh.shell is None or not len(contours.face) else mesh.shell[contours.face]
    for local in range(len(contours.layer_offsets) - 1):
        index = first_layer + local
        first, last = contours.layer_offsets[local], contours.layer_offsets[local + 1]
        start, stop = contours.offsets[first], contours.offsets[last]
        graded = None
        if grade is not None:
            parent = contours.parent[first:last]
            point_material = None
            if vertex_mix is not None:
                point_material = interpolate_at(vertex_mix, contours.point_edge[start:stop],
                                                contours.point_t[start:stop])
            graded = GradedJob(
                spec=grade,
                area=contours.area[first:last],
                parent=np.where(parent >= 0, parent - first, -1),
                loop_shell=None if loop_shell is None else loop_shell[first:last],
                point_material=point_material,
                channel_paths=tuple(directory / layer_file_name(index, channel_name(m)) for m in materials)
                if spec.channels else None,
                field=field, z=0.0 if z is None else float(z[index]),
                halftone=spec.halftone,
            )
        yield LayerJob(
            index=index,
            points=contours.points[start:stop],
            offsets=contours.offsets[first:last + 1] - start,
            grid=grid,
            dpi=spec.dpi,
            compression=spec.compression,
            layer_height_mm=spec.layer_height_mm,
            path=directory / layer_file_name(index),
            graded=graded,
        )
