"""The slice pipeline: a :class:`SliceSpec` in, a stack on disk out.

spec (what is asked, checked) -> materials (the material model: what a mesh's materials make of the
slice) -> slice_job (sizes checked, directory prepared, manifest last) -> runs (consecutive planes sliced,
chained, then rendered and written layer by layer) -> layer_job (one layer: render, encode, write; what it
leaves to the next), or parts (a multi-part job's layers: each part's loops rasterised on their own,
composed by priority); parallel holds every process matter (forks, workers, allocator, collector,
BLAS threads, dying with the parent).

The names below are loaded on first use (PEP 562), not when the package is imported: the ``heoslice``
command imports :mod:`heoslice.pipeline.parallel` to set its process up before numpy loads.
"""

from __future__ import annotations

from heoslice.lazy import lazy_exports

#: Public name -> the module of this package that defines it.
_EXPORTS = {
    "SliceSpec": "spec", "StageTimes": "spec", "channel_name": "spec", "MIN_LAYER_MM": "spec",
    "MIN_DPI": "spec", "MAX_DPI": "spec",
    "LayerJob": "layer_job", "GradedJob": "layer_job", "PipelineCache": "layer_job", "layer_jobs": "layer_job",
    "render_and_write": "layer_job",
    "RunContext": "runs", "RunResult": "runs", "run_contours": "runs", "slice_run": "runs", "plane_runs": "runs",
    "MAX_LAYER_MM": "spec", "MAX_MARGIN_MM": "spec", "MAX_CANVAS_MM": "spec", "MAX_JOBS": "spec",
    "MAX_COORDINATE_MM": "spec", "check_range": "spec", "check_scale": "spec",
    "slice_to_stack": "slice_job", "grading_summary": "slice_job",
    "layer_limit": "slice_job", "slice_warnings": "slice_job",
    "MaterialJob": "materials", "material_job": "materials",
    "run_all": "parallel", "keep_freed_memory": "parallel",
    "PartsPlan": "parts", "plan_parts": "parts", "part_order": "parts", "compose_part_masks": "parts",
}

__all__ = sorted(_EXPORTS)


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
