"""The ahead-of-time build of every compiled kernel (the mesh's, the slicing's, the chaining's, the
rasteriser's, the surface distance's, the grading's and Voxel Print's run stream): what each kernel Python
calls takes, and the compile.

Run by ``setup.py`` when heoslice is installed (never at run time: it needs numba, and kernels compiled
just in time, ``HEOSLICE_JIT=1``). Each kernel listed in :data:`heoslice.jit.ENTRIES` is exported
with the argument types of :data:`ARGUMENTS` (C-ordered arrays; the Python wrappers make them so) and the
return type numba infers for them, once per label width where it takes labels; a kernel and a table that
disagree stop the build. The extension also exports the digest of the sources it was made from and every
export's argument layout (JSON), which ``HEOSLICE_CHECK_KERNELS=1`` checks at each call (the test suite
does: a compiled kernel does not check what it is given).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

from numba import types
from numba.core.compiler import Flags
from numba.core.targetconfig import Option
from numba.pycc import CC
from numba.pycc import compiler as pycc_compiler

from heoslice.export import voxel_print_kernels
from heoslice.grading import (
    diffusion_kernels,
    droplets_kernels,
    edges_kernels,
    field_kernels,
    fit_kernels,
    halftone_kernels,
    labels_kernels,
    lattice_kernels,
    materials_kernels,
    pixel_mix_kernels,
    refine_kernels,
    search_kernels,
)
from heoslice.jit import (
    COMPILED_MODULES,
    DIGEST_EXPORT,
    ENTRIES,
    LABEL_BITS,
    LAYOUTS_EXPORT,
    export_name,
    source_digest,
)
from heoslice.layers import contours_kernels, packed_kernels, rasterising_kernels, slicing_kernels
from heoslice.material import surface_kernels, surface_layer_kernels
from heoslice.mesh import topology_kernels, weld_kernels
from heoslice.stack import report_kernels
from heoslice.volume import resample_kernels

f8, i8, b1 = types.float64, types.int64, types.boolean
f8_1, f8_2, f8_3, f8_4 = types.float64[::1], types.float64[:, ::1], types.float64[:, :, ::1], types.float64[:, :, :, ::1]
f4_1, f4_2, f4_3 = types.float32[::1], types.float32[:, ::1], types.float32[:, :, ::1]
i8_1, i8_2, i1_2 = types.int64[::1], types.int64[:, ::1], types.int8[:, ::1]
b_2, u1_2, u1_3 = types.boolean[:, ::1], types.uint8[:, ::1], types.uint8[:, :, ::1]
u4_2, u8_1, u8_3, u1_1 = types.uint32[:, ::1], types.uint64[::1], types.uint64[:, :, ::1], types.uint8[::1]

EDGES = types.NamedUniTuple(f8_1, 5, edges_kernels.EdgeArrays)
TREE = types.NamedTuple((f8_2, i8_1, f8_2), search_kernels.EdgeTree)
PIXELS = types.NamedTuple((i8, f8, f8), field_kernels.CellPixels)
FRAME = types.NamedUniTuple(f8, 4, lattice_kernels.LatticeFrame)
CELL_FIELD = types.NamedTuple((f8_2, f8_3, b_2, b_2, b_2), refine_kernels.CellField)
FIT_TEST = types.NamedUniTuple(f8, 5, refine_kernels.FitTest)
VERTICES = types.NamedTuple((i8_1, f8_1, f8_1, f8_1, f8, f8), refine_kernels.RingVertices)
ONE_RING_FIT = types.NamedUniTuple(f8, 10, fit_kernels.OneRingFit)
DIFFUSION_STATE = types.Tuple((f4_3, i8, i8, i8, f4_3))
DIFFUSION_SETTINGS = types.Tuple((f4_2, f4_1, f4_2, i8))
HIERARCHY = types.NamedTuple((f8_2, f8_2, i8_1, i8_1, i8_1, i8_1, f8_3, f8_2, f8_1, f8_2), surface_kernels.Hierarchy)
LAYER_FRAME = types.NamedUniTuple(f8, 5, surface_layer_kernels.LayerFrame)


#: The kernels' modules whose exports go into the second extension module (COMPILED_MODULES[1]); every other
#: module's go into the first. The build compiles the two in parallel processes, so this splits the compile
#: about in half: these (the grading field's fit, with the droplets) hold about half of numba's compile time,
#: measured per kernel (benchmarks/README.md).
SECOND_MODULE_KERNELS = frozenset({
    "heoslice.grading.droplets_kernels", "heoslice.grading.field_kernels", "heoslice.grading.edges_kernels",
    "heoslice.grading.fit_kernels", "heoslice.grading.refine_kernels",
})


def _target(bits: int) -> types.Type:
    """A LabelTarget of unsigned labels ``bits`` wide."""
    return types.NamedTuple((types.Array(getattr(types, f"uint{bits}"), 2, "C"), b_2, i8, i8, f8),
                            field_kernels.LabelTarget)


def _layer(bits: int) -> types.Type:
    """droplet_bits' labelled layer: unsigned labels ``bits`` wide, their origin, the packed solid mask and
    the labels' rows (the array holds them, or one row for all)."""
    return types.Tuple((types.Array(getattr(types, f"uint{bits}"), 2, "C"), i8, i8, u1_2, i8))


#: Argument types of every kernel that Python calls, by kernel (numba's dispatcher); a function of the label
#: width (bits) for the kernels that take labels.
ARGUMENTS: dict[Callable, tuple | Callable[[int], tuple]] = {
    contours_kernels._chain_loops: (i8_1, i8_1),
    diffusion_kernels._diffuse: (f4_3, types.UniTuple(i8, 2), DIFFUSION_STATE, DIFFUSION_SETTINGS, u1_3),
    diffusion_kernels._diffuse_labelled: lambda bits: (
        _layer(bits), types.Tuple((i8_1, f4_1, i8_2, f4_1, f4_1)), i8, DIFFUSION_STATE, DIFFUSION_SETTINGS, u1_3),
    droplets_kernels._agreed_choices: (f4_2, f4_1, f4_1, f4_1),
    droplets_kernels._droplet_bits: lambda bits: (
        _layer(bits), types.Tuple((i8_1, f4_1, i8_2, f4_1, f4_1)), types.Tuple((f4_2, i8_2, i1_2, i8)), u1_3),
    edges_kernels._straight_runs: (f8_1, f8_1, i8_1, f8, i8),
    edges_kernels._convex_rings: (f8_1, f8_1, f8_1, i8_1, f8),
    edges_kernels._kept_edges: (f8_2, i8_1, i8_1, types.boolean[::1], i8_1),
    field_kernels._band_field: (f8_3, f8_4, f8),
    halftone_kernels._void_and_cluster: (b_2, f8_2, f8_2),
    field_kernels._cell_classes: (f8_2, f8_2, f8_2, f8_3, f8, f8),
    field_kernels._curved_cells: (f8_3, b_2, b_2),
    field_kernels._expand_planes: lambda bits: (f8_2, f8_3, b_2, b_2, i8, PIXELS, f8, _target(bits)),
    field_kernels._curve_cells: lambda bits: (_target(bits), i8_1, i8_1, PIXELS, f8_2, f8),
    fit_kernels._one_ring_labels: lambda bits: (_target(bits), f8_2, f8_3, ONE_RING_FIT, PIXELS, types.UniTuple(f8, 4),
                                                f4_1, f4_1, TREE, EDGES),
    labels_kernels._disc_winding: (f8_2, i8_1, i8_1, f8, f8, f8),
    lattice_kernels._signed_feet: (i8_2, FRAME, EDGES, b_2, b1),
    lattice_kernels._inside_centres: (EDGES, f8_1, FRAME, i8, i8),
    lattice_kernels._feet: (f8_1, f8_1, i8_1, EDGES),
    lattice_kernels._block_bounds: (EDGES, TREE, FRAME, i8, i8),
    lattice_kernels._block_passes: (EDGES, f8_1, TREE, FRAME, i8, i8, b1),
    lattice_kernels._block_edges: (i8_2, f8_2, b_2, FRAME, i8, i8, EDGES, TREE),
    materials_kernels._values_at_points: (f8_1, f8_1, i8_1, EDGES, i8_1, i8_1, f8_1, f8_2),
    packed_kernels.fold_words: (u8_1, u8_1, i8, i8, i8, i8_1),
    rasterising_kernels._packed_mask: (f8_2, i8_1, i8, i8, f8, f8, f8, f8, u1_2),
    refine_kernels._refine_flags: (CELL_FIELD, types.UniTuple(f8_2, 3), FIT_TEST, VERTICES),
    refine_kernels._hessian_of: (f8_3, f8, f8),
    refine_kernels._vertices_by_cell: (f8_1, f8_1, f8_1, f8, f8, f8, f8, i8, i8),
    refine_kernels._ring_models: (f8_3, f8_4, f8_3, i8_1, i8_1, f8, f8, f8, f8, f8),
    refine_kernels._band_cells: lambda bits: (_target(bits), i8_1, i8_1, PIXELS, f8_3, f4_2, i8_2, f8, f8),
    refine_kernels._measured_cells: lambda bits: (_target(bits), i8_1, i8_1, PIXELS, types.UniTuple(f8, 4), f8_1,
                                                 f4_1, f4_1, TREE, EDGES, f8, f8),
    pixel_mix_kernels.quadratic_planes: (u1_2, i8, i8, types.UniTuple(f8, 4), types.UniTuple(f8, 6), f8, f8,
                                         types.uint16[::1], types.int32[:, ::1], i8, i8, u1_3),
    pixel_mix_kernels.step_planes: (u1_2, i8, i8, types.uint16[:, ::1], types.uint16[::1], types.int32[:, ::1], i8, i8,
                                    u1_3),
    report_kernels.design_tally: (u1_2, u1_3, i8_1, types.uint16[:, ::1], f4_1, i8_1, i8, i8, i8, i8_1, i8_1, i8_1,
                                  i8, i8_1, i8_2, f8_2, f8_1),
    search_kernels._candidates: (f8_1, f8_1, f8_1, f8_2, i8_1),
    search_kernels._nearest_in_batches: (f8_1, f8_1, f8_1, f4_1, f4_1, TREE, EDGES, b1),
    search_kernels._chunks_apart: (i8_1, i8_1, f8_2, f8_2, f8_2, f8_2, f8),
    search_kernels._tree_boxes: (f8_1, f8_1, f8_1, f8_1, i8_1),
    search_kernels._chunk_capsules: (f8_1, f8_1, f8_1, f8_1),
    slicing_kernels._layer_segments: (f8_2, i8_2, f8_1, i8_1, i8_1),
    surface_kernels.build_nodes: (f8_2, f8_2, f8_2, i8),
    surface_kernels.nearest_distances: (f8_2, HIERARCHY, f8_1),
    surface_layer_kernels.layer_r: (u1_2, i8, i8, LAYER_FRAME, HIERARCHY, f8, f8, f8, i8, f8_2, f8_2, i8,
                                    types.uint16[:, ::1]),
    topology_kernels._edge_runs: (i8_2, i8),
    topology_kernels._lowest_connected: (i8_1, i8_1, i8),
    voxel_print_kernels._run_stream: (u8_3, i8_1, i8, i8_1, i8_2, u8_1, i8_1, u1_1, i8, u1_1),
    weld_kernels._first_rows: (u8_1, u4_2),
    resample_kernels._label_codes: (types.float32[:, :, ::1], f4_1, types.uint8[::1], i8_2, f8, i8_1, f4_1, i8_1,
                                    f4_1, u1_3, i8_1),
}


def layout_of(numba_type: types.Type):
    """What HEOSLICE_CHECK_KERNELS compares an argument with: "DTYPE NDIMd" for a (C-ordered) array, "int",
    "float" or "bool" for a scalar, a list of those for a tuple."""
    if isinstance(numba_type, types.Array):
        return f"{numba_type.dtype} {numba_type.ndim}d"
    if isinstance(numba_type, types.BaseTuple):
        return [layout_of(item) for item in numba_type.types]
    return {types.int64: "int", types.float64: "float", types.boolean: "bool"}[numba_type]


def _forwarding(dispatcher: Callable) -> Callable:
    """A function of the kernel's arguments that calls it: the export, compiled with the kernel's own options
    (fast-math or exact) because it calls the kernel's dispatcher rather than being it."""
    names = dispatcher.py_func.__code__.co_varnames[:dispatcher.py_func.__code__.co_argcount]
    namespace = {"kernel": dispatcher}
    exec(f"def forward({', '.join(names)}):\n    return kernel({', '.join(names)})\n", namespace)  # noqa: S102
    return namespace["forward"]


class _GilReleasingFlags(Flags):
    """numba's compile flags with the GIL released around each export's native code, as ``nogil`` releases it
    around a kernel compiled just in time (numba.pycc's own flags hold it): threads may then run kernels side by
    side (the surface distance measures its chunks in threads)."""

    release_gil = Option(type=bool, default=True, doc="Release the GIL inside the native function")


def module_part(entry) -> int:
    """Which extension module of COMPILED_MODULES (0 or 1) an entry of ENTRIES is compiled into."""
    return int(entry.dispatcher.py_func.__module__ in SECOND_MODULE_KERNELS)


def compile_kernels(directory: Path, filename: str, part: int = 0) -> Path:
    """Compile the kernels of ENTRIES that go into extension module ``part`` (:func:`module_part`) into
    ``directory/filename`` (the module COMPILED_MODULES[part]), for this machine's processor as numba's
    just-in-time compilation would; returns its path."""
    listed = {entry.dispatcher for entry in ENTRIES}
    if listed != set(ARGUMENTS):
        names = sorted(kernel.__name__ for kernel in listed ^ set(ARGUMENTS))
        raise RuntimeError(f"the kernels and the export table disagree on {', '.join(names)}")
    cc = CC(COMPILED_MODULES[part].rsplit(".", 1)[1])
    cc.output_dir, cc.output_file, cc.target_cpu = str(directory), filename, "host"
    layouts = {}
    for entry in (entry for entry in ENTRIES if module_part(entry) == part):
        function = entry.dispatcher.py_func
        arguments = ARGUMENTS[entry.dispatcher]
        variants = ([(None, arguments)] if entry.label_arg is None
                    else [(bits, arguments(bits)) for bits in LABEL_BITS])
        for bits, argument_types in variants:
            entry.dispatcher.compile(argument_types)
            returns = entry.dispatcher.overloads[argument_types].signature.return_type
            name = export_name(function, bits)
            cc.export(name, returns(*argument_types))(_forwarding(entry.dispatcher))
            layouts[name] = [layout_of(t) for t in argument_types]
    digest, layouts_json = source_digest(), json.dumps(layouts)

    def digest_of_sources():
        return digest

    def argument_layouts():
        return layouts_json

    cc.export(DIGEST_EXPORT, types.int64())(digest_of_sources)
    cc.export(LAYOUTS_EXPORT, types.unicode_type())(argument_layouts)
    holding, pycc_compiler.Flags = pycc_compiler.Flags, _GilReleasingFlags
    try:
        cc.compile()
    finally:
        pycc_compiler.Flags = holding
    return directory / filename
