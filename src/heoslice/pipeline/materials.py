"""The material model of a slice: what a mesh's materials make of it, from mesh to printer (issue 18).

One rule, :func:`material_job`, decides per mesh:

- A mesh carries materials when it has a per-vertex material fraction (``heoslice color`` writes it:
  m mixes (1 - m) M1 + m M2, exactly), vertex or face colours that map to more than one material of
  the table (each colour to the material of nearest display colour,
  :func:`heoslice.material.nearest_materials`), or a grading specification (``--grade``, per-shell
  materials).
- Such a mesh gets a :class:`heoslice.grading.GradeSpec` even without ``--grade``: every solid pixel takes
  the material of its contour, at the nearest point of the contour's outer ring (section III.A's Z-axis
  distribution over the whole layer, not a one-pixel ring).
- A stack that holds more than one material writes one 1-bit droplet mask per material per layer (the
  print job) unless asked for an RGBA preview stack; a one-material stack stays a 1-bit solid mask.

Each vertex's material is a mix over the spec's channel materials ((n, K) float, rows summing to 1),
interpolated along the sliced edges like any vertex attribute.

A model ``heoslice color`` made carries its design (:class:`heoslice.material.design.Design`): its material
fraction is the share of the design's named target (M2) against its start (M1), whatever their places in the
materials table, and its interior is by default the design's field evaluated at every voxel in 3D
(``interior`` ``field``, :mod:`heoslice.material.field`); ``contour`` carries the contour's material inward
(the rule above), ``graded`` is ``--grade``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from heoslice.errors import InputError
from heoslice.material import (
    DEFAULT_MATERIALS,
    Material,
    check_one_per_channel,
    material_roles,
    nearest_materials,
    same_material,
    with_table_channels,
)
from heoslice.mesh import Mesh
from heoslice.pipeline.spec import SliceSpec


@dataclass(frozen=True)
class MaterialJob:
    """A slice's spec as the mesh's materials settle it, and each vertex's material mix ((n, K) float
    over ``spec.grade.channel_materials()``, or None where every contour keeps the spec's own materials)."""

    spec: SliceSpec
    vertex_mix: np.ndarray | None
    field: object | None = None


def _plain_grade(table: tuple[Material, ...]):
    """The grading specification of a mesh that carries materials but asks for no gradient: every
    family keeps its contour's material, the table's first two playing M1 and M2."""
    from heoslice.grading import GradeSpec, RegionSpec  # the grading package loads its kernels and shapely

    roles = material_roles({m.name: m for m in table})
    return GradeSpec(regions=RegionSpec(), function=None, target=None, start=None,
                     base=roles.first, second=roles.second)


def _masks_used(grade, mesh: Mesh):
    """``grade`` without its second material when nothing mixes towards it (no gradient, no material
    fraction): colours and shells name their own materials, so a table material the mesh does not use
    gets no mask, nor a printer channel to share."""
    if grade is None or grade.function is not None or mesh.material is not None:
        return grade
    return replace(grade, second=None)


def _fraction_mix(fraction: np.ndarray, grade) -> np.ndarray:
    """(n, K) mix of a per-vertex material fraction m ((n,) float): 1 - m of the base, m of the second
    (:func:`heoslice.grading.materials.point_mixes`, the one place that rule is written)."""
    from heoslice.grading.materials import point_mixes  # grading is loaded already: _plain_grade or --grade

    return point_mixes(grade, np.nan_to_num(np.asarray(fraction, dtype=np.float64)))


def _table(spec: SliceSpec) -> tuple[Material, ...]:
    """The materials colours map to: the spec's table (the built-in M1, M2 when empty), with its channels as a
    materials file's get them (keyed by position: names may repeat)."""
    return tuple(with_table_channels(dict(enumerate(spec.materials or DEFAULT_MATERIALS.values()))).values())


def colour_collapse(mesh: Mesh, spec: SliceSpec) -> str | None:
    """One line when the mesh's distinct colours (at least 3, no material fraction) map onto fewer materials of
    the table (a scan's shades onto M1 and M2): how many onto which, and what to do for more; else None."""
    if spec.parts is not None or mesh.material is not None or mesh.colors is None:
        return None
    rgb = np.asarray(mesh.colors)[:, :3].astype(np.int64)
    packed = np.unique((rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2])
    distinct = np.stack([packed >> 16, (packed >> 8) & 255, packed & 255], axis=1)
    table = _table(spec)
    used = [table[index].name for index in np.unique(nearest_materials(distinct, table))]
    if len(distinct) < 3 or len(distinct) <= len(used):
        return None
    return (f"its {len(distinct)} distinct colours map onto {len(used)} material{'s' if len(used) > 1 else ''} "
            f"({', '.join(used)}), each colour to the material of nearest display colour: the stack holds only "
            f"{'these' if len(used) > 1 else 'this one'} (list more materials with --materials FILE.toml, or "
            "grade between two with heoslice color)")


def one_material(mesh: Mesh, spec: SliceSpec) -> str | None:
    """The name of the material a one-material slice of ``mesh`` is made of (None when the slice holds several,
    or is a multi-part job): the one its colours all map to, else the table's first (M1 by the default roles)."""
    if spec.parts is not None or material_job(mesh, spec).spec.grade is not None:
        return None
    table = _table(spec)
    if mesh.colors is not None and mesh.material is None and len(mesh.colors):
        return table[int(nearest_materials(np.asarray(mesh.colors)[:1, :3], table)[0])].name
    return material_roles({m.name: m for m in table}).first.name


def _design(mesh: Mesh, spec: SliceSpec):
    """The slice's design: the spec's (the command line settled it), else the mesh's own record with its
    materials settled against ``spec.materials`` (:func:`heoslice.material.design.settle_materials`); None for
    a model without one or without a material fraction."""
    if mesh.material is None:
        return None
    if spec.design is not None:
        return spec.design
    from heoslice.material.design import design_of, settle_materials

    design = design_of(mesh)
    if design is None:
        return None
    table = {m.name: m for m in with_table_channels({m.name: m for m in spec.materials}).values()}
    return settle_materials(design, table or None, "the materials table", str(mesh.source))


def _interior(spec: SliceSpec, design) -> str:
    """What the solid of a model gets (:data:`heoslice.material.design.INTERIORS`): the spec's, checked against
    what the model and the grading allow, else the default (the field for a model with a design)."""
    graded = spec.grade is not None and spec.grade.function is not None
    if spec.interior is None:
        return "graded" if graded else "field" if design is not None and not design.shells else "contour"
    if spec.interior == "graded" and not graded:
        raise InputError("interior: 'graded' needs a distribution function to grade with (grade)")
    if spec.interior != "graded" and graded:
        raise InputError(f"interior: a graded slice (grade) is 'graded', not {spec.interior!r}")
    if spec.interior == "field" and design is None:
        raise InputError("interior: 'field' evaluates the design heoslice color records in the model; this "
                         "model has none (colour it with heoslice color, or use 'contour')")
    if spec.interior == "field" and design.shells:
        raise InputError("interior: 'field' does not colour shells whole; a design with shell colours is "
                         "sliced with 'contour'")
    return spec.interior


def _designed(grade, design):
    """``grade`` with the design's roles: its fraction mixes the design's start (base) and target (second), a
    gradient that ``--to`` names no target for grades towards the design's target (its start when ``--from`` names
    the target: never from a material to itself), and its shells coloured whole keep their material (a materials
    file's [shells] entry wins)."""
    target = grade.target
    if grade.function is not None and not grade.target_named:
        named_start = grade.start is not None and same_material(grade.start, design.target)
        target = design.start if named_start else design.target
    return replace(grade, base=design.start, second=design.target, target=target,
                   shells=tuple(sorted({**dict(design.shells), **dict(grade.shells)}.items())))


def material_job(mesh: Mesh, spec: SliceSpec) -> MaterialJob:
    """The material model of slicing ``mesh`` with ``spec`` (the module's rule); ``spec.materials`` is the
    table colours map to (the built-in M1, M2 when empty)."""
    if spec.parts is not None:  # a multi-part job: each part is one material (heoslice.pipeline.parts)
        return MaterialJob(spec, None)
    table = _table(spec)
    grade, mix, field = _masks_used(spec.grade, mesh), None, None
    design = _design(mesh, spec)
    interior = _interior(spec, design)
    spec = replace(spec, design=design, interior=interior)
    if mesh.material is not None:
        grade = grade if grade is not None else _plain_grade(table)
        if design is not None:
            grade = _designed(grade, design)
        if interior == "field":
            from heoslice.material.field import material_field

            field = material_field(design, mesh.source)
            spec = replace(spec, design=field.design)  # its surface where the slice found it
        elif grade.second is not None:
            mix = _fraction_mix(mesh.material, grade)
    elif mesh.colors is not None:
        chosen = nearest_materials(mesh.colors, table)
        used = np.unique(chosen)
        if len(used) > 1 or grade is not None:
            grade = grade if grade is not None else _masks_used(_plain_grade(table), mesh)
            grade = replace(grade, mapped=tuple(table[i] for i in used))
            columns = np.array([grade.channel_index(table[i]) for i in used])
            mix = np.zeros((len(chosen), len(grade.channel_materials())))
            mix[np.arange(len(chosen)), columns[np.searchsorted(used, chosen)]] = 1.0
    wanted = spec.channels
    if grade is None and wanted is None and spec.materials and spec.materials[0].channel is not None:
        # one material of a materials file, on its printer channel: its droplet mask records which, and where
        grade, wanted = _masks_used(_plain_grade(table), mesh), True
    if grade is None:
        return MaterialJob(replace(spec, channels=bool(wanted)), None)
    several = len(grade.channel_materials()) > 1
    if not several and grade.function is None and wanted is None:
        return MaterialJob(replace(spec, grade=None, channels=False), None)
    channels = several if wanted is None else wanted
    if channels:
        grade = grade.with_printer_channels(table)
        check_one_per_channel(grade.channel_materials(), "the droplet masks")
    if grade.function is not None and grade.regions.depth_from == "surface":
        field = _surface_depth_field(mesh, grade, mix)
    return MaterialJob(replace(spec, grade=grade, channels=channels), mix, field)


def _surface_depth_field(mesh: Mesh, grade, mix):
    """The field of ``--grade ... --depth D --depth-from surface``: from the start material (``--from``, else the
    base) at the model's surface to the target at depth D, r the exact 3-D distance to the surface over D in
    eq. 8's N_R sub-regions of the nozzle's width (or ``--offsets``)."""
    from heoslice.grading.spec import band_count
    from heoslice.material.design import Design, ReferenceRecord
    from heoslice.material.field import depth_field

    if mix is not None and grade.start is None:
        raise InputError("depth_from: grading from the 3-D surface starts from one material: name it with --from "
                         "(this model's contours carry several)")
    regions = grade.regions
    bands = regions.count if regions.count is not None else band_count(regions.depth_mm, regions.nozzle_mm)
    start = grade.start if grade.start is not None else grade.base
    design = Design(start, grade.target, ReferenceRecord("surface"), grade.function, (0.0, regions.depth_mm))
    return depth_field(mesh.vertices, mesh.faces, design, bands)
