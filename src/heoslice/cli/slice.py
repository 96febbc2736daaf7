"""``heoslice slice``: mesh in, verified layer stack out."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import click

from heoslice.cli.common import (
    echo_json,
    echo_warnings,
    expand_inputs,
    plural,
    progress_bar,
    run_each,
)
from heoslice.cli.info import refuse_stack_as_model
from heoslice.cli.options import apply_scale, flags, function_from_options, function_options, option, scale_option
from heoslice.cli.parts import REFUSALS, is_parts_job, part_settings, report_parts
from heoslice.cli.volume import slice_volume, volume_options
from heoslice.errors import InputError
from heoslice.grading.halftone import DEFAULT_METHOD, METHODS
from heoslice.material import MaterialsFile, material_roles, read_materials_file
from heoslice.mesh import Mesh, load_assembly, load_mesh, without_materials
from heoslice.pipeline import SliceSpec, one_material, plan_parts, slice_to_stack, slice_warnings
from heoslice.pipeline.printers import PRESETS, PrinterPreset, presets_table, printer_preset
from heoslice.stack import COMPRESSIONS, DEFAULT_COMPRESSION, print_refusal, refusal_line, stack_volume_mm3
from heoslice.volume import is_volume_path

#: SliceSpec and slice_to_stack parameters -> the options that set them (library errors name the parameter).
SPEC_FLAGS = {
    "layer_height_mm": "--layer", "dpi": "--dpi", "margin_mm": "--margin", "canvas_mm": "--canvas",
    "compression": "--compress", "jobs": "--jobs", "channels": "--channels", "materials": "--materials",
    "scale": "--scale", "interior": "--interior", "halftone": "--halftone", "printer": "--printer",
}


def default_output(model: Path, parent: Path | None = None) -> Path:
    """Where a stack goes without -o: ``<model stem>_stack`` in ``parent`` (--into), else the current directory (a
    relative path, so reports name it as a user would, as ``verify`` and ``print`` name what they are given)."""
    return (parent if parent is not None else Path()) / f"{model.stem}_stack"


def stack_directories(models: tuple[Path, ...], output: Path | None, into: Path | None) -> dict[Path, Path]:
    """Each model's stack directory; two models that would share one are refused before anything is sliced."""
    targets = {model: output if output is not None else default_output(model, into) for model in models}
    seen: dict[Path, Path] = {}
    for model, directory in targets.items():
        other = seen.setdefault(directory.absolute(), model)
        if other != model:
            raise InputError(f"{other} and {model} would both be sliced into {directory}; "
                             "slice them in separate calls or rename one")
    return targets


def flag_message(text: str) -> str:
    """``text`` with the parameter it starts with (``layer_height_mm: ...``) named as its option."""
    parameter, colon, rest = text.partition(":")
    flag = SPEC_FLAGS.get(parameter)
    return f"{flag}:{rest}" if colon and flag else text


def flag_error(err: InputError) -> InputError:
    """``err`` with the parameter its message starts with named as its option (:func:`flag_message`)."""
    shown = flag_message(str(err))
    return InputError(shown) if shown != str(err) else err


def parse_dpi(text: str) -> tuple[float, float]:
    """'600' -> (600, 600); '600x300' -> (600, 300). Raises InputError otherwise."""
    parts = str(text).lower().split("x")
    try:
        values = [float(part) for part in parts]
    except ValueError:
        values = []
    if len(values) == 1:
        values = values * 2
    if len(values) != 2 or not all(value > 0 for value in values):
        raise InputError(f"--dpi: expected N or NxM with positive numbers, got {text!r}")
    return (values[0], values[1])


def parse_canvas(text: str | None) -> tuple[float, float] | None:
    """'200x150' (mm) -> (200.0, 150.0)."""
    if text is None:
        return None
    try:
        width, height = (float(part) for part in text.lower().split("x"))
    except ValueError:
        raise InputError(f"--canvas: expected WxH in mm (e.g. 200x150), got {text!r}") from None
    if not (width > 0 and height > 0):
        raise InputError(f"--canvas: width and height must be positive, got {text!r}")
    return (width, height)


def refuse_options_without_grade(alpha, beta, lam, periods, expression, depth, offset_count, target, start) -> None:
    """InputError naming the grading options given without --grade (they would be ignored)."""
    given = {"--alpha": alpha, "--beta": beta, "--lambda": lam, "--periods": periods,
             "--expr": expression, "--depth": depth, "--offsets": offset_count}
    stray = [name for name, value in given.items() if value is not None]
    stray += [name for name, value in {"--to": target, "--from": start}.items() if value]
    if stray:
        raise InputError(f"{', '.join(stray)}: only used with --grade FUNC (ignored without it)")


def grade_spec(kind, alpha, beta, lam, periods, expression, target, start, nozzle, depth, offset_count,
               direction, materials: MaterialsFile, channels, depth_from: str = "layer"):
    """The GradeSpec the grading options ask for, or None when none is given: the mesh's own materials then
    decide (:func:`heoslice.pipeline.material_job`).

    Per-shell materials in the materials file, or --channels, without --grade still build one: the
    families keep their own (or their shell's) materials, without a gradient; --to, --from and the
    function's coefficients without --grade are refused (they would be ignored). The materials (of the
    file, read once by the caller) play the parts :func:`heoslice.material.material_roles` gives them.
    """
    if kind is None:
        refuse_options_without_grade(alpha, beta, lam, periods, expression, depth, offset_count, target, start)
    with option("--materials"):
        shells = materials.shells()
    if kind is None and not (channels or shells):
        return None
    # imported here, past the plain path's return: the grading package loads its kernels and shapely
    from heoslice.grading import GradeSpec, RegionSpec

    table = materials.materials
    function = None if kind is None else function_from_options("--grade", kind, alpha, beta, lam, periods,
                                                                expression)
    with flags({"start": "--from", "target": "--to"}):
        roles = material_roles(table, start=start, target=target)
    return GradeSpec(
        regions=RegionSpec(nozzle_mm=nozzle, depth_mm=depth, direction=direction, count=offset_count,
                           depth_from=depth_from),
        function=function, target=roles.m2 if function is not None else roles.target, start=roles.start,
        base=roles.first, second=roles.second, shells=tuple(sorted(shells.items())), target_named=bool(target),
    )


@click.command("slice", epilog="""\b
Examples:
  heoslice slice vase.ply                       # 0.1 mm layers, 600 dpi, into ./vase_stack/
  heoslice slice vase_linear.ply                # `color`'s output: M1 and M2 droplet masks per layer
  heoslice slice vase_linear.ply --rgba         # a preview-only RGBA stack in the materials' colours
  heoslice slice liver.ply --layer 0.1 --dpi 600 -o liver_stack
  heoslice slice part.stl --dpi 600x300 --canvas 200x150 --compress packbits
  heoslice slice scan.ply --scale 1000 --json   # a model in metres
  heoslice slice "scans/*.ply" --into stacks/   # one stack per model: stacks/NAME_stack
  heoslice slice liver.ply --printer j750-27um  # the J750's 600x300 dpi grid and 27 um layers
  heoslice slice --printer list                 # the printer presets
\b
Coloured models (heoslice color's output):
  heoslice slice vase_linear.ply                       # the design's field at every voxel, in 3D
  heoslice slice vase_linear.ply --interior contour    # each layer's contour material carried inward
\b
Graded interiors (the paper's Fig. 3b, 9b):
  heoslice slice model.ply --grade linear --to 0,255,0 --nozzle 0.2
  heoslice slice liver.ply --grade linear --depth 8 --depth-from surface   # skins graded in 3D
  heoslice slice vase.ply --grade linear --to 0,255,0 --offsets 200
  heoslice slice liver.ply --grade sine --periods 2 --to M2 --depth 10
  heoslice slice part.ply --grade linear --from M1 --to M2 --direction out --materials mats.toml
  heoslice slice liver.ply --grade linear --to M2 --halftone error-diffusion
\b
Several parts in one stack (a multi-part job; one 1-bit droplet mask per material per layer):
  heoslice slice liver.stl lesion.stl vessels.stl --materials mats.toml -o liver_stack   # mats.toml has [parts]
  heoslice slice liver.stl lesion.stl --parts --part liver=M1 --part lesion=M2
  heoslice slice organ.3mf --materials mats.toml  # each 3MF object is a part
  A part is named by its file's stem or its 3MF object's name; its material is the one [parts] or
  --part names, else its 3MF base material's name if that is a table material, else the table
  material nearest its one colour. Where parts overlap the higher [parts] priority wins, then
  the smaller part (so an enclosed lesion wins over its organ). Not graded: --grade is refused.
\b
Volumes (a label map: NIfTI .nii/.nii.gz, NRRD or Slicer .seg.nrrd, a folder of one NIfTI per structure):
  heoslice slice example_seg.nii.gz --materials organs.toml   # organs.toml's [labels]: 5 = "tissue"
  heoslice slice segmentation.seg.nrrd --materials mats.toml  # [labels] by segment name: "liver" = "gel"
  heoslice slice totalseg_output/ --up A                      # printer +z = the patient's anterior
  heoslice slice ct.nii.gz --materials ct.toml                # a CT through ct.toml's [intensity] curve
  heoslice slice ct.nii.gz --labels seg.nii.gz --materials ct.toml   # bone by density, [labels] as tissue
  Each label's surface is smoothed between voxel centres; labels not listed in [labels] are left out
  (without a [labels] table every label prints, in the table's first material).
""")
@click.argument("models", nargs=-1, type=click.Path(path_type=Path), metavar="MODEL...")
@click.option("-o", "--output", type=click.Path(path_type=Path), default=None,
              help="Stack directory, for one model [default: ./MODEL_stack].")
@click.option("--into", type=click.Path(path_type=Path, file_okay=False), default=None, metavar="DIR",
              help="Put each model's stack in DIR/MODEL_stack (any number of models) [default: .].")
@click.option("--layer", "layer_height", type=float, default=0.1, show_default=True,
              help="Layer height, mm.")
@click.option("--dpi", default="600", show_default=True, help="Resolution: N, or NxM for x and y.")
@click.option("--canvas", default=None, help="Fixed build area WxH in mm, part centred [default: part + margin].")
@click.option("--margin", type=float, default=1.0, show_default=True, help="Empty border around the part, mm.")
@click.option("--compress", "compression", type=click.Choice(list(COMPRESSIONS)), default=DEFAULT_COMPRESSION,
              show_default=True, help="Lossless TIFF compression.")
@scale_option
@click.option("-j", "--jobs", type=int, default=0, show_default=True, help="Worker processes (0 = all cores).")
@click.option("--force", is_flag=True, help="Overwrite a non-empty output directory.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary instead of text.")
@click.option("--grade", "grade_kind", default=None, metavar="FUNC",
              help="Grade each layer's interior from the contour's material to --to with this distribution "
                   "function: constant, linear, quadratic, sine or expression (eq. 2-5).")
@function_options
@click.option("--to", "target", default=None, metavar="MATERIAL",
              help="Target material M2 reached at r = 1: a name from the materials file, #hex or r,g,b "
                   "[default with --grade: a coloured model's design target (its start when --from names the "
                   "target), else the second material, M2 (the first when --from names M2)].")
@click.option("--from", "start", default=None, metavar="MATERIAL",
              help="Start material M1 at the contour [default: the contour's own material].")
@click.option("--nozzle", type=float, default=0.2, show_default=True,
              help="Nozzle diameter D_N, mm: N_R = int(L_S / D_N) sub-regions (eq. 8).")
@click.option("--depth", type=float, default=None,
              help="Grade to this depth (L_S, mm) from the contour instead of to the inner rings "
                   "[default: to the holes, or to the deepest point].")
@click.option("--depth-from", "depth_from", type=click.Choice(["layer", "surface"]), default="layer",
              show_default=True,
              help="Measure --depth from each layer's own contour (the paper's offset sub-regions, eq. 8-10: a "
                   "top or bottom skin comes out thinner or thicker than the sides) or from the model's 3-D "
                   "surface (the exact point-to-mesh distance: every skin graded alike; needs --depth).")
@click.option("--offsets", "offset_count", type=int, default=None,
              help="Number of sub-regions N_R instead of eq. 8 (the paper's Fig. 3b used 200).")
@click.option("--direction", type=click.Choice(["in", "out"]), default="in", show_default=True,
              help="Offset the outer ring inwards, or the inner rings outwards.")
@click.option("--materials", "materials_file", type=click.Path(path_type=Path), default=None,
              help="Materials file (TOML): names, display colours, channels, per-shell materials.")
@click.option("--channels/--rgba", "channels", default=None,
              help="Droplet masks (one 1-bit mask per material per layer, beside the 1-bit solid mask; the "
                   "print job), or an RGBA preview stack in the materials' display colours instead "
                   "[default: masks whenever the stack holds more than one material; a one-material "
                   "model stays a solid mask either way].")
@click.option("--interior", type=click.Choice(["field", "contour"]), default=None,
              help="What the solid of a model coloured by `heoslice color` gets: 'field', the design's f(r) at "
                   "every voxel from its own 3-D distance to the reference (the distribution of section II.B "
                   "evaluated in 3D), or 'contour', the material of the nearest point of the voxel's layer "
                   "contour carried inward (the paper's layer-wise Z-axis distribution, section III.A) "
                   "[default: field for a model carrying a design; contour for other coloured models; "
                   "--grade is the paper's eq. 8-10 sub-regions].")
@click.option("--printer", default=None, metavar="NAME",
              help=f"Printer preset: its resolution, layer pitch, width padding and material limit in one word "
                   f"({', '.join(PRESETS)}); 'list' shows them. An explicit --dpi or --layer must agree with it.")
@click.option("--halftone", type=click.Choice(list(METHODS)), default=DEFAULT_METHOD, show_default=True,
              help="How each pixel's mix becomes one material's droplet: "
                   + "; ".join(f"{name}: {line}" for name, line in METHODS.items()) + ".")
@click.option("--solid", "solid_only", is_flag=True,
              help="One material: ignore the mesh's material fractions and colours (a 1-bit solid mask per "
                   "layer; not with --grade or --channels).")
@click.option("--parts", "parts_flag", is_flag=True,
              help="Slice every MODEL as a part of ONE stack, each part's pixels carrying its material "
                   "[implied by --part, a 3MF model or a [parts] table in --materials].")
@click.option("--part", "part_options", multiple=True, metavar="NAME=MATERIAL",
              help="Material of the part NAME (a file's stem or a 3MF object's name) in a multi-part job; "
                   "repeat for each part (overrides the materials file's [parts]).")
@volume_options
@click.pass_context
def slice_cmd(ctx: click.Context, models: tuple[Path, ...], output: Path | None, into: Path | None,
              layer_height: float, dpi: str, canvas: str | None,
              margin: float, compression: str, scale: float, jobs: int, force: bool, as_json: bool,
              grade_kind: str | None, alpha: float | None, beta: float | None, lam: float | None,
              periods: float | None, expression: str | None, target: str | None, start: str | None,
              nozzle: float, depth: float | None, depth_from: str, offset_count: int | None, direction: str,
              materials_file: Path | None, channels: bool | None, interior: str | None, printer: str | None,
              halftone: str, solid_only: bool, parts_flag: bool, part_options: tuple[str, ...], up: str,
              smooth: float | None, label_map: Path | None, volume_kind: str | None) -> None:
    """Slice each MODEL (PLY, STL, OBJ, OFF, 3MF) into one TIFF per layer plus manifest.json.

    Layers are cut at their centres, z = z_min + (i + 1/2) x layer; a pixel is solid
    when its centre is inside the model. The stack format is in docs/stack-format.md.

    A model that carries materials (the material fraction `heoslice color` writes,
    colours that map to more than one material of the table, per-shell materials) or a
    graded slice gives a multi-material stack: each layer's 1-bit solid mask plus one
    1-bit droplet mask per material, what `heoslice print` sends. Colours map to the
    material of nearest display colour. A one-material model gives the solid mask alone.

    \b
    What the interior of a coloured model gets (--interior; recorded in the manifest):
      field    a model from `heoslice color` (it records its design): every solid voxel
               jets f(r) of its own 3-D distance to the design's reference, with the
               r normalisation color used (the default for such a model)
      contour  every solid pixel takes the material of the nearest point of its layer's
               contour (the paper's layer-wise Z-axis distribution; the default for
               other coloured models, e.g. colour scans)
      graded   --grade FUNC: the paper's offset sub-regions (eq. 8-10) from the contour's
               material to --to; --depth-from surface measures --depth in 3D instead
    The design's materials are the stack's: the fraction is the share of the material
    named as its target. With --materials each must be in the file, with the same colour
    and channel (else one error line naming both); without, they are used as recorded.

    Several models (or a quoted pattern such as "scans/*.ply", expanded by heoslice)
    each go to their own stack; one that fails is reported and the others still run.
    With --parts (or --part, a 3MF, a [parts] table) they are the parts of one stack.
    """
    if printer == "list":
        click.echo("\n".join(presets_table()))
        return
    if not models:
        raise click.UsageError("Missing argument 'MODEL...'.")
    try:
        preset = None if printer is None else printer_preset(printer)
    except InputError as err:
        raise flag_error(err) from None
    if preset is not None:
        layer_height, dpi = preset_grid(ctx, preset, layer_height, dpi)
    with option("--materials"):
        materials = read_materials_file(materials_file)  # the one read of the file: its tables are passed on
    # a coloured mesh's interior and the preview stack, typed on this command line (a defaults file's [slice]
    # settings of them stay for the coloured meshes it is also used for)
    typed_for_meshes = {name for name in ("interior", "channels")
                        if ctx.get_parameter_source(name) is click.core.ParameterSource.COMMANDLINE}
    interior_given, rgba_given = interior is not None and "interior" in typed_for_meshes, (
        channels is False and "channels" in typed_for_meshes)
    for model in models:
        refuse_stack_as_model(model)
    if len(models) == 1 and is_volume_path(models[0]):
        if (grade_kind is not None or parts_flag or part_options or solid_only or scale != 1.0 or interior_given
                or rgba_given):
            raise InputError("a volume is sliced by its labels: --grade, --parts, --part, --solid, --scale, --interior "
                             "and --rgba do not apply (map labels to materials in the materials file's [labels] "
                             "table; its stack is a print job: see it with heoslice preview STACK)")
        if into is not None:
            raise click.UsageError("--into: one volume makes one stack; name it with -o/--output")
        try:
            spec = SliceSpec(layer_height_mm=layer_height, dpi=parse_dpi(dpi), margin_mm=margin,
                             canvas_mm=parse_canvas(canvas), compression=compression, jobs=jobs,
                             halftone=halftone, printer=preset)  # halftone: [grade] labels', [intensity] mixes
        except InputError as err:
            raise flag_error(err) from None
        slice_volume(models[0], output, spec, force, as_json, materials, bool(channels), up, smooth, volume_kind,
                     label_map)
        return
    volumes = [model for model in models if is_volume_path(model)]
    if volumes:
        raise InputError(f"{volumes[0]}: a volume is sliced on its own, one volume per run (with "
                         f"{plural(len(models) - 1, 'other model')} here); give each its own heoslice slice")
    # typed on this command line (a defaults file's [slice] volume settings stay for the volumes it is also used for)
    typed = {name for name in ("up", "smooth", "label_map", "volume_kind")
             if ctx.get_parameter_source(name) is click.core.ParameterSource.COMMANDLINE}
    given = [flag for flag, name, value in (("--up", "up", up != "S"), ("--smooth", "smooth", smooth is not None),
                                            ("--labels", "label_map", label_map is not None),
                                            ("--as", "volume_kind", volume_kind is not None))
             if value and name in typed]
    if given:
        raise InputError(f"{given[0]}: only used when slicing a volume (NIfTI, NRRD, a folder), not a mesh")
    if is_parts_job(models, parts_flag, part_options, materials):
        given = [flag for flag, value in (("--grade", grade_kind is not None), ("--interior", interior_given),
                                           ("--rgba", rgba_given)) if value]
        if given:
            raise InputError(REFUSALS[given[0]])
        refuse_options_without_grade(alpha, beta, lam, periods, expression, depth, offset_count, target, start)
        if into is not None:
            raise click.UsageError("--into: a multi-part job makes one stack; name it with -o/--output")
        slice_parts(models, output, dict(layer_height_mm=layer_height, dpi=parse_dpi(dpi), margin_mm=margin,
                                         canvas_mm=parse_canvas(canvas), compression=compression, jobs=jobs,
                                         printer=preset),
                    scale, force, as_json, materials, part_options, bool(channels))
        return
    if solid_only and (grade_kind is not None or channels or interior):
        raise InputError("--solid: slices one material; it cannot be combined with --grade, --channels or "
                         "--interior")
    if interior is not None and grade_kind is not None:
        raise InputError(f"--interior: --grade grades the interior by eq. 8-10 sub-regions; it cannot be "
                         f"combined with --interior {interior}")
    if depth_from != "layer" and grade_kind is None:
        raise InputError("--depth-from: only used with --grade FUNC (ignored without it)")
    grade = grade_spec(grade_kind, alpha, beta, lam, periods, expression, target, start, nozzle, depth,
                       offset_count, direction, materials, channels, depth_from)
    try:
        spec = SliceSpec(layer_height_mm=layer_height, dpi=parse_dpi(dpi), margin_mm=margin,
                         canvas_mm=parse_canvas(canvas), compression=compression, jobs=jobs,
                         grade=grade, channels=channels, materials=materials_table(materials), interior=interior,
                         halftone=halftone, printer=preset)
    except InputError as err:
        raise flag_error(err) from None
    inputs = expand_inputs(models)
    if inputs.several and output is not None:
        raise click.UsageError("-o/--output names one stack; with several models use --into DIR")
    if output is not None and into is not None:
        raise click.UsageError("give -o/--output (one stack) or --into DIR, not both")
    targets = stack_directories(inputs.paths, output, into)
    run_each(inputs, lambda model: slice_model(model, targets[model], spec, scale, force, as_json, inputs.several,
                                               solid_only, materials=materials),
             key="model", as_json=as_json, debug=(ctx.find_root().obj or {}).get("debug", False))


def preset_grid(ctx: click.Context, preset: PrinterPreset, layer_height: float, dpi: str) -> tuple[float, str]:
    """The layer height (mm) and --dpi text a printer preset slices at; InputError when --layer or --dpi was
    given (on the command line or in heoslice.toml) with another value."""
    wanted_dpi = f"{preset.dpi[0]:g}x{preset.dpi[1]:g}"
    for name, flag, value, agrees in (
            ("layer_height", "--layer", f"{layer_height:g} mm", lambda: float(layer_height) == preset.layer_mm),
            ("dpi", "--dpi", str(dpi), lambda: parse_dpi(dpi) == preset.dpi)):
        given = ctx.get_parameter_source(name) not in (click.core.ParameterSource.DEFAULT, None)
        if given and not agrees():
            wanted = f"{preset.layer_mm:g} mm" if name == "layer_height" else wanted_dpi
            raise InputError(f"{flag}: {value} disagrees with --printer {preset.name} ({wanted}); give one or the "
                             "other")
    return preset.layer_mm, wanted_dpi


def materials_table(materials: MaterialsFile) -> tuple:
    """The materials of the materials file in file order (() without one: the built-in M1, M2)."""
    return () if materials.path is None else tuple(materials.materials.values())


def material_line(names: list[str], masks: bool, mode: str) -> str:
    """What a stack's layers hold, for the summary line: e.g. 'materials M1, M2: a solid mask and 2 droplet
    masks per layer'."""
    if masks:
        return f"materials {', '.join(names)}: a solid mask and {plural(len(names), 'droplet mask')} per layer"
    if mode == "RGBA":
        return f"materials {', '.join(names)}: an RGBA preview image per layer (no droplet masks: not a print job)"
    return f"one material{f' ({names[0]})' if names else ''}: a solid mask per layer"


def slice_parts(models: tuple[Path, ...], output: Path | None, spec_fields: dict, scale: float, force: bool,
                as_json: bool, materials: MaterialsFile, part_options: tuple[str, ...], channels: bool) -> None:
    """A multi-part job: every part loaded (a failing file is named before anything is written), their
    materials and priorities planned, then one stack sliced and reported (:mod:`heoslice.cli.parts`)."""
    inputs = expand_inputs(models)
    missing = [item for item in inputs.items if isinstance(item, str)]
    if missing:
        raise InputError(f"{missing[0]}: no file matches this pattern")
    mesh = load_assembly(inputs.paths)
    table, settings = part_settings(materials, part_options, [part.name for part in mesh.parts])
    try:
        spec = SliceSpec(**spec_fields, parts=plan_parts(mesh.parts, table, settings, channels=channels))
    except InputError as err:
        raise flag_error(err) from None
    directory = output if output is not None else default_output(inputs.paths[0])
    summary = slice_model(mesh.source, directory, spec, scale, force, as_json, False, mesh=mesh,
                          inputs=(*inputs.paths, *((materials.path,) if materials.path else ())))
    if as_json:
        echo_json(summary)


def model_design(mesh: Mesh, scale: float, materials: MaterialsFile | None):
    """The design ``heoslice color`` recorded in the model (None without one), at the slice's ``--scale``, its
    materials settled against the materials file (:func:`heoslice.material.design.settle_materials`: without
    a file the design's own materials are the stack's)."""
    from heoslice.material.design import design_of, settle_materials

    design = design_of(mesh)
    if design is None or mesh.material is None:
        return None
    table = None if materials is None or materials.path is None else materials.materials
    return settle_materials(design.scaled(scale), table, str(None if materials is None else materials.path),
                            str(mesh.source))


def slice_model(model: Path, directory: Path, spec: SliceSpec, scale: float, force: bool, as_json: bool,
                several: bool, solid_only: bool = False, mesh: Mesh | None = None,
                inputs: tuple[Path, ...] | None = None, materials: MaterialsFile | None = None) -> dict:
    """Slice one model (``mesh`` when it is loaded already) into ``directory`` and report it (one text line,
    two for a multi-part job, or nothing with --json); its summary. ``solid_only`` slices it as one
    material, whatever it carries; a design the model carries is followed (:func:`model_design`, its
    materials checked against ``materials``, the materials file)."""
    mesh = load_mesh(model) if mesh is None else mesh
    if solid_only:
        mesh = without_materials(mesh)
    elif spec.parts is None:
        spec = replace(spec, design=model_design(mesh, scale, materials))
    mesh = apply_scale(mesh, scale)
    if not as_json:
        echo_warnings(model, [*mesh.warnings, *(flag_message(text) for text in slice_warnings(mesh, spec))])
    with progress_bar(f"slicing {model.name}" if several else "slicing", enabled=not as_json) as update:
        try:
            manifest, times = slice_to_stack(mesh, directory, spec, force=force, progress=update, scale=scale,
                                             inputs=inputs)
        except InputError as err:
            raise flag_error(err) from None
    open_layers = [entry["index"] for entry in manifest["layers"] if entry["open_contours"]]
    refusal = print_refusal(manifest)
    unprintable = [refusal_line(refusal, directory)] if refusal is not None and refusal.slice_warns else []
    materials = (manifest.get("grading") or {}).get("materials") or []
    masks = bool(manifest["layers"]) and "channels" in manifest["layers"][0]
    only = None if materials else one_material(mesh, spec)
    summary = {
        "model": str(model),
        "ok": True,
        "stack": str(directory),
        "layers": len(manifest["layers"]),
        "image": [manifest["image"]["width"], manifest["image"]["height"]],
        "dpi": manifest["dpi"],
        "volume_mm3": stack_volume_mm3(manifest),
        "materials": [m["name"] for m in materials] if materials else [only] if only else [],
        "droplet_masks": masks,
        "open_contour_layers": open_layers,
        "warnings": [*mesh.warnings, *unprintable],
        **({"parts": manifest["parts"]} if "parts" in manifest else {}),
        "seconds": {"slice": times.slice, "contours": times.contours, "raster_cpu": times.raster,
                    "encode_cpu": times.encode, "total": times.total},
    }
    if as_json:
        return summary
    if open_layers:
        shown = ", ".join(str(i) for i in open_layers[:10]) + (" ..." if len(open_layers) > 10 else "")
        click.echo(f"warning: {model}: open mesh: contours closed in {len(open_layers)} layer(s): {shown}",
                   err=True)
    for text in unprintable:
        click.echo(f"warning: {text}", err=True)
    click.echo(f"{directory}: {plural(summary['layers'], 'layer')} of "
               f"{summary['image'][0]} x {summary['image'][1]} px "
               f"at {manifest['dpi'][0]:g} x {manifest['dpi'][1]:g} dpi, volume {summary['volume_mm3']:.1f} mm^3, "
               f"{times.total:.1f} s; {material_line(summary['materials'], masks, manifest['image']['mode'])}")
    if "parts" in manifest:
        report_parts(directory, manifest)
    sys.stdout.flush()
    return summary
