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

#: Each module of this package -> the public names it defines.
_MODULES = {
    "spec": ("SliceSpec", "StageTimes", "channel_name", "MIN_LAYER_MM", "MIN_DPI", "MAX_DPI", "MAX_LAYER_MM",
             "MAX_MARGIN_MM", "MAX_CANVAS_MM", "MAX_JOBS", "MAX_COORDINATE_MM", "check_range", "check_scale"),
    "layer_job": ("LayerJob", "GradedJob", "PipelineCache", "layer_jobs", "render_and_write"),
    "runs": ("RunContext", "RunResult", "run_contours", "slice_run", "plane_runs"),
    "slice_job": ("slice_to_stack", "grading_summary", "layer_limit", "slice_warnings"),
    "materials": ("MaterialJob", "material_job", "one_material"),
    "parallel": ("run_all", "keep_freed_memory"),
    "parts": ("PartsPlan", "plan_parts", "part_order", "compose_part_masks"),
    "volume_job": ("LabelPlan", "plan_labels", "slice_volume_to_stack"),
}

__all__, __getattr__, __dir__ = lazy_exports(__name__, _MODULES)
