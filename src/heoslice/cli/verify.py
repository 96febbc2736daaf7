"""``heoslice verify``: check a stack before printing it, optionally against the mesh it came from."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import click

from heoslice.cli import material_report
from heoslice.cli.common import plural, progress_bar, signed_percent
from heoslice.errors import HeosliceError, InputError, VerifyError
from heoslice.pipeline.parallel import ordered_map
from heoslice.volume import is_volume_path
from heoslice.stack import (
    check_input_path,
    layer_height_problems,
    print_refusal,
    read_manifest,
    refusal_line,
    source_scale,
    stack_volume_mm3,
    verify_stack,
)

if TYPE_CHECKING:  # the mesh stage loads only with --mesh: a plain verify starts quicker
    from heoslice.mesh import Mesh


def part_files(manifest: dict) -> list[tuple[str, str]]:
    """The files a multi-part stack's parts came from, each once, in the manifest's part order: (file name,
    sha256) pairs; [] for a stack without parts. A 3MF's objects are one file."""
    parts = manifest.get("parts")
    if not isinstance(parts, list):
        return []
    return list(dict.fromkeys((str(part.get("file")), str(part.get("sha256"))) for part in parts
                              if isinstance(part, dict)))


def check_mesh_count(stack: Path, manifest: dict, models: tuple[Path, ...]) -> None:
    """One --mesh per file the stack's parts came from, or one for a stack of one file; InputError (one line)
    otherwise, naming the files the stack needs in their order."""
    files = part_files(manifest)
    if len(models) == max(1, len(files)):
        return
    if len(files) > 1:
        raise InputError(f"--mesh: {stack} was sliced from the {len(files)} part files "
                         f"{', '.join(name for name, _ in files)}: give one --mesh for each, in that order "
                         f"(got {len(models)})")
    raise InputError(f"--mesh: {stack} was sliced from one mesh file: give one --mesh (got {len(models)})")


def source_warnings(manifest: dict, mesh: Mesh, models: tuple[Path, ...]) -> list[str]:
    """A warning per mesh file that is not the one the stack was sliced from (its sha256 differs): each part
    file's against its --mesh with several, else the stack's source against the one mesh."""
    if len(models) > 1:
        given = {Path(part.source): part.sha256 for part in mesh.parts}
        return [f"{model}: not the file of the stack's parts from {name} (sha256 differs)"
                for model, (name, digest) in zip(models, part_files(manifest)) if given.get(Path(model)) != digest]
    source = manifest.get("source")
    if isinstance(source, dict) and source.get("sha256") not in (None, mesh.sha256):
        return [f"{mesh.source}: not the file this stack was sliced from "
                f"({source.get('file', '?')}, sha256 differs)"]
    return []


def mesh_checks(manifest: dict, mesh: Mesh, scale: float, tolerance: float,
                models: tuple[Path, ...] = ()) -> tuple[list[str], list[str], dict]:
    """Compare a stack with its (scaled) mesh (of the --mesh files ``models``): which files they are, volume
    (the library's rule) and layers against the z-range.

    Returns (problems, warnings, summary).
    """
    model = mesh.source
    problems: list[str] = []
    warnings = [f"{model}: {text}" for text in mesh.warnings] + source_warnings(manifest, mesh, models)
    from heoslice.mesh import volume_check

    volume = volume_check(mesh, stack_volume_mm3(manifest), tolerance)
    problems += [volume.problem] if volume.problem else []
    warnings += [volume.warning] if volume.warning else []
    z_min, z_max = (float(v) for v in mesh.bounds[:, 2])
    problems += layer_height_problems(manifest, z_min, z_max, "the mesh's")
    summary = {"file": str(model), "scale": scale, "watertight": volume.watertight,
               "volume_mm3": volume.mesh_volume_mm3, "relative_volume_difference": volume.relative,
               "z_range_mm": [z_min, z_max]}
    return problems, warnings, summary


def volume_checks(manifest: dict, model: Path, tolerance: float) -> tuple[list[str], list[str], dict]:
    """Compare a volume's stack with the label map it was sliced from: which file it is, and the stack's volume
    against the voxel volume of the labels its manifest lists as printed. Returns (problems, warnings, summary)."""
    from heoslice.volume import load_volume
    from heoslice.volume.info import printed_voxel_volume_mm3

    records = manifest.get("labels")
    if not isinstance(records, list):  # asked before the file is read as labels (a CT's are refused there)
        raise InputError(f"--mesh: {model} is a volume, but this stack lists no printed labels (not sliced from one)")
    volume = load_volume(model, "labels")
    warnings = [] if (manifest.get("source") or {}).get("sha256") in (None, volume.sha256) else [
        f"{model}: not the file this stack was sliced from (its sha256 differs from the manifest's)"]
    expected = printed_voxel_volume_mm3(volume, records)
    relative = (stack_volume_mm3(manifest) - expected) / expected if expected else float("inf")
    problems = [] if abs(relative) <= tolerance else [
        f"stack volume {stack_volume_mm3(manifest):.6g} mm^3 differs from the printed labels' voxel volume "
        f"{expected:.6g} mm^3 by {100 * relative:+.2f} % (tolerance {100 * tolerance:g} %)"]
    return problems, warnings, {"file": str(model), "scale": 1.0, "watertight": None, "volume_mm3": expected,
                                "relative_volume_difference": relative, "z_range_mm": manifest["z_range_mm"]}


def mesh_scale(stack: Path, manifest: dict, given: float | None) -> float:
    """The factor to multiply the --mesh coordinates by: the ``scale`` the stack's manifest records (``slice
    --scale``), or ``given`` (--scale) for a stack that records none (1 without either). A ``given`` that
    disagrees with the recorded one is an InputError (one line)."""
    if "scale" not in manifest:
        return 1.0 if given is None else given
    recorded = source_scale(manifest)
    if given is not None and abs(given - recorded) > 1e-9 * recorded:
        raise InputError(f"--scale: {given:g} disagrees with the scale {recorded:g} {stack} was sliced with (its "
                         "manifest records it); leave --scale out")
    return recorded


def in_part_order(manifest: dict, models: tuple[Path, ...]) -> tuple[Path, ...]:
    """The --mesh files of a multi-part stack in the order of its parts' files, matched by content (sha256) when
    each is a file the stack was sliced from, in whatever order they were given; as given otherwise (then
    :func:`source_warnings` names the ones that differ)."""
    files = part_files(manifest)
    if len(models) < 2 or len(files) != len(models):
        return models
    from heoslice.mesh import file_sha256

    try:
        by_digest = {file_sha256(model): model for model in models}
    except (OSError, HeosliceError):  # a file that cannot be read: loading it reports it
        return models
    if set(by_digest) != {digest for _, digest in files}:
        return models
    return tuple(by_digest[digest] for _, digest in files)


def _check_mesh_options_first(stack: Path, models: tuple[Path, ...],
                              given: float | None) -> tuple[float, tuple[Path, ...]]:
    """:func:`check_mesh_count` and :func:`mesh_scale` before any mesh is loaded or layer hashed (both are
    known from the manifest alone): the scale, and the --mesh files :func:`in_part_order`. A manifest that
    cannot be read is left to verify_stack's problem lines (the scale is then ``given``, or 1)."""
    try:
        manifest = read_manifest(stack)
    except VerifyError:
        return (1.0 if given is None else given), models
    check_mesh_count(stack, manifest, models)
    return mesh_scale(stack, manifest, given), in_part_order(manifest, models)


@click.command("verify", epilog="""\b
Examples:
  heoslice verify vase_stack/
  heoslice verify vase_stack/ --mesh vase.ply
  heoslice verify scan_stack/ --mesh scan.ply --json   # sliced with --scale 1000: the stack remembers
  heoslice verify liver_stack/ --mesh liver.stl --mesh lesion.stl   # a multi-part stack: one per part file
  heoslice slice vase.ply --grade linear --rgba -o vase_design        # the design, as a preview stack
  heoslice verify vase_stack/ --design vase_design                   # every 2 mm window against it
  heoslice verify seg_stack/ --mesh example_seg.nii.gz   # a volume's stack: its labels' voxel volume
  heoslice slice ball_c.ply --dpi 600 -o ball_stack   # a model heoslice color designed: field interior
  heoslice verify ball_stack/                         # against its recorded design, per band of r
""")
@click.argument("stack", type=click.Path(path_type=Path))
@click.option("--mesh", "models", type=click.Path(path_type=Path), multiple=True,
              help="Also compare volume and layer heights with this mesh file; for a multi-part stack (slice "
                   "--parts) repeat it, one per part file in the order they were sliced.")
@click.option("--scale", type=click.FloatRange(min=0.0, min_open=True), default=None,
              help="Scale the mesh was sliced with ('heoslice slice --scale'), for a stack whose manifest does "
                   "not record it [default: the manifest's scale, else 1].")
@click.option("--tolerance", type=click.FloatRange(min=0.0), default=0.01, show_default=True,
              help="Largest relative volume difference accepted with --mesh (0.01 = 1 %).")
@click.option("--design", "preview", type=click.Path(path_type=Path), default=None, metavar="PREVIEW_STACK",
              help="The --rgba preview stack of the same slice: compare every 2 mm x 2 mm window (one every "
                   "quarter window, 0.466 mm at 600 dpi) of a two-material graded or coloured stack with the mix "
                   "its colours design, as shares of the target the manifest records (a field-interior stack is "
                   "compared with the design its manifest records without it).")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
def verify(stack: Path, models: tuple[Path, ...], scale: float | None, tolerance: float, preview: Path | None,
           as_json: bool) -> None:
    """Check STACK before printing: manifest (format, version, complete), every layer file
    (inside the stack, present, sha256, size, dpi, solid pixel count), no missing or extra
    layers, and that it can print (not an RGBA preview, not every layer empty); with --mesh
    also the volume and layer heights against the mesh (the parts' meshes together, one
    --mesh per part file, for a multi-part stack). A stack sliced from a volume (label map)
    takes the volume as --mesh: its volume is compared with the printed labels' voxel volume.

    Prints one line per problem; a pixel in two droplet masks, or a solid one in none,
    is named by layer, pixel and mm. A stack whose files pass is followed by what it
    delivers: each material's voxels, mm^3 and share of the solid; each part's designed
    against delivered share (a multi-part stack); with --design, the worst 2 mm x 2 mm
    window (at least 47 pixels a side: larger on a stack coarser than 600 dpi; windows
    start every quarter window across and down each layer: 11 pixels, 0.466 mm, at
    600 dpi; the size and step are printed) and each band of designed share of the
    recorded target (grading.target) against the design. A stack sliced with the
    field interior from a designed model is compared with the design its manifest
    records: f(r) per pixel computed again, 10 bands of r and the worst window (a missing
    or changed reference surface is a warning, and no comparison). A band or window more
    than 2 points off the design is a problem. Exit status 0 only when the stack is
    clean, 4 when it has problems, 2 when STACK or the mesh cannot be read.
    """
    check_input_path(stack)
    mesh = None
    volume_model = models[0] if len(models) == 1 and is_volume_path(models[0]) else None
    if models and volume_model is None:
        scale, models = _check_mesh_options_first(stack, models, scale)
        from heoslice.mesh import load_assembly, load_mesh, scaled

        mesh = load_mesh(models[0]) if len(models) == 1 else load_assembly(models)
        mesh = scaled(mesh, scale) if scale != 1.0 else mesh
    recorded = None if preview is not None else material_report.RecordedWork(stack)
    with progress_bar("verifying", enabled=not as_json) as progress:
        report = verify_stack(stack, progress=progress, layer_map=ordered_map, also=recorded)
    problems, warnings, mesh_summary = list(report.problems), [], None
    if mesh is not None and report.manifest:
        mesh_problems, warnings, mesh_summary = mesh_checks(report.manifest, mesh, scale, tolerance, models)
        problems += mesh_problems
    elif volume_model is not None and report.manifest:
        mesh_problems, warnings, mesh_summary = volume_checks(report.manifest, volume_model, tolerance)
        problems += mesh_problems
    refusal = print_refusal(report.manifest) if report.manifest else None
    problems += [refusal_line(refusal, stack)] if refusal is not None else []
    layers = report.manifest.get("layers", []) if report.manifest else []
    delivered = None
    if report.ok and layers:
        delivered = material_report.compute(stack, report.manifest, mesh, preview, warnings, problems, recorded,
                                            report.also)
    summary = {
        "stack": str(stack),
        "ok": not problems,
        "problems": problems,
        "warnings": warnings,
        "layers": len(layers),
        "volume_mm3": stack_volume_mm3(report.manifest) if report.manifest else None,
        "mesh": mesh_summary,
        "delivered": None if delivered is None else material_report.as_json(report.manifest, *delivered),
    }
    if as_json:
        click.echo(json.dumps(summary))
    else:
        for text in warnings:
            click.echo(f"warning: {text}", err=True)
        for line in problems:
            click.echo(line if line.startswith(str(stack)) else f"{stack}: {line}")
        compared = "labels' voxel volume" if volume_model else "mesh volume"
        if not problems:
            click.echo(f"{stack}: OK, {plural(len(layers), 'layer')}, volume {summary['volume_mm3']:.6g} mm^3"
                       + (f", {compared} {mesh_summary['volume_mm3']:.6g} mm^3 "
                          f"({signed_percent(mesh_summary['relative_volume_difference'])})"
                          if mesh_summary and mesh_summary["relative_volume_difference"] is not None else ""))
        for line in [] if delivered is None else material_report.text_lines(report.manifest, *delivered):
            click.echo(line)
    sys.stdout.flush()
    if problems:
        raise VerifyError(f"{stack}: {len(problems)} problem(s); do not print this stack")
