"""Runs of planes: the whole pipeline (slice, chain, render, write) for consecutive layers at once.

A run is sliced and chained in one go (bounded by ``SliceSpec.max_segments`` segments, so memory does
not grow with the part), then its layers are rendered and written one by one.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from heoslice.layers.contours import Contours, build_contours
from heoslice.layers.rasterising import Grid
from heoslice.layers.slicing import plane_chunks, slice_planes
from heoslice.mesh import Mesh
from heoslice.pipeline.layer_job import PipelineCache, layer_jobs, render_and_write
from heoslice.pipeline.spec import SliceSpec

#: Most planes in a run, by halftone (None: any other): error diffusion's runs are short, so that its layers (the
#: costliest to render) spread over the workers evenly; its error starts afresh at each run.
RUN_LAYERS = {None: 32, "error-diffusion": 8}
#: A run's contours with the seconds spent slicing and chaining them: (contours, slice s, chain s).
SlicedRun = tuple[Contours, float, float]


@dataclass(frozen=True)
class RunContext:
    """What every run of planes needs: the mesh, the planes ((L,) float, mm), each face's z-range
    ((m,) lowest and highest, mm), the grid, the spec (as
    :func:`heoslice.pipeline.materials.material_job` settled it), the stack directory and each vertex's
    material mix ((n, K) float or None, :class:`heoslice.pipeline.materials.MaterialJob`) or the design's field
    (the ``field`` interior)."""

    mesh: Mesh
    z: np.ndarray
    face_range: tuple[np.ndarray, np.ndarray]
    grid: Grid
    spec: SliceSpec
    directory: Path
    vertex_mix: np.ndarray | None = None
    field: object | None = None

    @cached_property
    def run_starts(self) -> frozenset[int]:
        """The first plane of each run of :func:`plane_runs`: where an error-diffusion halftone starts afresh,
        whichever process renders the run (the layer after the parent's first is not one)."""
        return frozenset(start for start, _ in plane_runs(self))


@dataclass(frozen=True)
class RunResult:
    """One run's layers (render_and_write results), its open-contour layers and stage seconds."""

    layers: list
    open_layers: np.ndarray
    slice_s: float
    contours_s: float


def run_contours(context: RunContext, start: int, stop: int) -> SlicedRun:
    """The contours of planes z[start:stop], with the seconds spent slicing and chaining them."""
    mesh = context.mesh
    began = time.perf_counter()
    sections = slice_planes(mesh.vertices, mesh.faces, context.z, start, stop, context.face_range)
    sliced = time.perf_counter()
    contours = build_contours(sections, hierarchy=context.spec.grade is not None)
    return contours, sliced - began, time.perf_counter() - sliced


def slice_run(context: RunContext, start: int, stop: int, cache: PipelineCache | None = None,
              on_layers: Callable[[int], None] | None = None) -> RunResult:
    """Slice, chain, render and write planes z[start:stop]: the whole pipeline for one run of layers.

    ``cache`` keeps what the last layer rendered leaves to the next (:class:`PipelineCache`); kept from run
    to run, it carries that over to the next run's first layer too, but for the error a diffused layer leaves
    to the next: dropped at the start of every run of :func:`plane_runs`, so that the stack is the same
    however its runs were shared among processes. ``on_layers(count)`` is told of the layers written as they
    are (one at a time; a multi-part run's all at once).
    """
    if cache is not None and context.spec.halftone == "error-diffusion" and start in context.run_starts:
        cache.carry = None
    contours, slice_s, contours_s = run_contours(context, start, stop)
    if context.spec.parts is not None:  # a multi-part job: each part's loops on their own, composed by priority
        from heoslice.pipeline.parts import render_parts_run

        layers = render_parts_run(contours, context, start)
        if on_layers is not None:
            on_layers(len(layers))
    else:
        jobs = layer_jobs(contours, context.mesh, context.grid, context.spec, context.directory,
                          first_layer=start, vertex_mix=context.vertex_mix, field=context.field, z=context.z)
        cache = PipelineCache() if cache is None else cache
        layers = []
        for job in jobs:
            layers.append(render_and_write(job, cache))
            if on_layers is not None:
                on_layers(1)
    return RunResult(layers=layers, open_layers=start + contours.layer[contours.closed_by_join],
                     slice_s=slice_s, contours_s=contours_s)


def plane_runs(context: RunContext, max_layers: int | None = None) -> list[tuple[int, int]]:
    """Runs of at most ``spec.max_segments`` segments and ``max_layers`` planes (memory and load balance; by
    default :data:`RUN_LAYERS` of the spec's halftone)."""
    if max_layers is None:
        max_layers = RUN_LAYERS.get(context.spec.halftone, RUN_LAYERS[None])
    runs = []
    for start, stop in plane_chunks(context.mesh.vertices, context.mesh.faces, context.z,
                                    context.spec.max_segments, context.face_range):
        runs += [(first, min(first + max_layers, stop)) for first in range(start, stop, max_layers)]
    return runs
