"""``heoslice slice`` of a volume (a label map: NIfTI, NRRD/.seg.nrrd, a folder of structure files): the
options it adds, the labels' materials from the materials file, the slice and its report."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from heoslice.cli.common import echo_json, echo_warnings, plural, progress_bar
from heoslice.errors import InputError
from heoslice.material import MaterialsFile
from heoslice.pipeline import SliceSpec
from heoslice.stack import stack_volume_mm3

#: File-name endings dropped to name a volume's default stack (example_seg.nii.gz -> example_seg_stack).
VOLUME_ENDINGS = (".seg.nrrd", ".nii.gz", ".nii", ".nrrd", ".nhdr")


def volume_stem(path: Path) -> str:
    """A volume's name without its format's endings."""
    name = path.name.rstrip("/") or path.resolve().name
    for ending in VOLUME_ENDINGS:
        if name.lower().endswith(ending):
            return name[: -len(ending)]
    return name


def volume_options(command):
    """The options ``slice`` takes for a volume."""
    command = click.option("--up", type=click.Choice(["S", "I", "A", "P", "R", "L"]), default="S", show_default=True,
                           help="Volumes: the anatomical direction that becomes the printer's +z (S superior, I "
                                "inferior, A anterior, P posterior, R right, L left).")(command)
    command = click.option("--smooth", type=float, default=None, metavar="VOXELS",
                           help="Volumes: the blur (sigma, voxels) that smooths each label's surface between voxel "
                                "centres [default: 0.3 x the label's largest inscribed radius, 1.5 .. 3].")(command)
    command = click.option("--labels", "label_map", type=click.Path(path_type=Path), default=None, metavar="MAP",
                           help="Volumes: with a CT (intensity) MODEL, its label map on the same grid: [labels] "
                                "print as labels, the labels the [intensity] table's 'within' lists by the "
                                "CT's values through its curve.")(command)
    return click.option("--as", "volume_kind", type=click.Choice(["labels", "intensity"]), default=None,
                        help="Volumes: read as a label map or an intensity volume [default: guessed].")(command)


def slice_volume(model: Path, output: Path | None, spec: SliceSpec, force: bool, as_json: bool,
                 materials: MaterialsFile, channels: bool, up: str, smooth: float | None, kind: str | None,
                 label_map: Path | None = None) -> None:
    """Load the label map at ``model``, plan its labels' materials ([labels]), slice it and report (a CT: by
    its [intensity] curve, with ``label_map`` restricting it to labels)."""
    from heoslice.pipeline.volume_job import plan_labels, slice_volume_to_stack
    from heoslice.volume import load_volume
    from heoslice.volume.model import check_label_keys
    from heoslice.volume.readers import GUESS_WARN_LABELS

    if smooth is not None and not 0 <= smooth <= 10:
        raise InputError(f"--smooth: must be from 0 to 10 voxels, got {smooth:g}")
    table = materials.data.get("intensity")
    if label_map is None and isinstance(table, dict) and "within" in table:
        raise InputError(f"{materials.path}: [intensity] within lists labels of a CT's label map: give that label "
                         "map with --labels MAP (or remove 'within')")
    volume = load_volume(model, kind)
    grades = ()
    if "grade" in materials.data:
        from heoslice.pipeline.volume_grading import read_grades

        if label_map is not None or volume.kind != "labels":
            raise InputError(f"{materials.path}: [grade] grades labels of a label map; slice the label map itself")
        grades = read_grades(materials.data["grade"], materials.materials, f"{materials.path}: [grade]")
        check_label_keys(volume, [key for grade in grades for key in (grade.label, grade.toward) if key is not None],
                         f"{materials.path}: [grade]")
    if label_map is None and volume.kind == "intensity" and materials.has_labels:
        raise InputError(f"{materials.path}: [labels] maps a label map's labels, but {model} is an intensity volume: "
                         "give its label map with --labels MAP (or remove [labels])")
    if label_map is not None:
        if volume.kind != "intensity":
            raise InputError(f"--labels: {model} is a label map; --labels goes with a CT (an intensity volume)")
        slice_ct_with_labels(model, volume, load_volume(label_map, "labels"), output, spec, force, as_json, materials,
                             up, smooth)
        return
    if volume.kind != "labels":
        slice_intensity(model, volume, output, spec, force, as_json, materials, up)
        return
    settings = materials.labels() if materials.has_labels else None
    if settings is None and volume.kind_guessed and len(volume.labels) > GUESS_WARN_LABELS:
        raise InputError(f"{model}: read as a label map of {len(volume.labels)} values (guessed from its whole-number "
                         "voxels) and, with no [labels] table, all would print as one block; if it is an intensity "
                         "image (a CT) say --as intensity, to print every label say --as labels")
    check_label_keys(volume, settings or (), f"{materials.path}: [labels]")
    plan = plan_labels(volume, materials.materials, settings, channels)
    directory = output if output is not None else Path.cwd() / f"{volume_stem(model)}_stack"
    if not as_json:
        echo_warnings(model, [*volume.warnings, *plan.warnings])
    with progress_bar("slicing", unit="layer") as update:
        manifest, times = slice_volume_to_stack(volume, directory, spec, plan, up=up, smooth=smooth, force=force,
                                                progress=update, grades=grades)
    names = [entry["name"] for entry in manifest["grading"]["materials"]] if manifest.get("grading") else \
        [material.name for material in plan.materials]
    summary = {"model": str(model), "ok": True, "stack": str(directory), "layers": len(manifest["layers"]),
               "image": [manifest["image"]["width"], manifest["image"]["height"]], "dpi": manifest["dpi"],
               "volume_mm3": stack_volume_mm3(manifest), "materials": names,
               "droplet_masks": bool(manifest.get("grading")), "labels": manifest["labels"],
               "placement": manifest["placement"],
               "warnings": list(manifest["warnings"]), "seconds": {"fields": times.slice, "raster_cpu": times.raster,
                                                                  "encode_cpu": times.encode, "total": times.total}}
    if as_json:
        echo_json(summary)
        return
    masks = f"a solid mask and {plural(len(names), 'droplet mask')} per layer" if summary["droplet_masks"] else \
        "one material: a solid mask per layer"
    click.echo(f"{directory}: {plural(summary['layers'], 'layer')} of {summary['image'][0]} x {summary['image'][1]} px "
               f"at {manifest['dpi'][0]:g} x {manifest['dpi'][1]:g} dpi, volume {summary['volume_mm3']:.1f} mm^3, "
               f"{times.total:.1f} s; {plural(len(plan.labels), 'label')}, {masks}")
    sys.stdout.flush()


def slice_intensity(model: Path, volume, output: Path | None, spec: SliceSpec, force: bool, as_json: bool,
                    materials: MaterialsFile, up: str) -> None:
    """Slice an intensity volume (a CT) through the materials file's [intensity] curve, and report."""
    from heoslice.pipeline.volume_job import slice_intensity_to_stack
    from heoslice.volume.intensity import read_curve

    if "intensity" not in materials.data:
        raise InputError(f"{model}: an intensity volume: slicing it needs an [intensity] curve (value -> blend of "
                         "materials) in the --materials file; or slice its label map, or say --as labels")
    curve = read_curve(materials.data["intensity"], materials.materials, f"{materials.path}: [intensity]")
    directory = output if output is not None else Path.cwd() / f"{volume_stem(model)}_stack"
    if not as_json:
        echo_warnings(model, volume.warnings)
    with progress_bar("slicing", unit="layer") as update:
        manifest, times = slice_intensity_to_stack(volume, directory, spec, curve, up=up, force=force,
                                                   progress=update)
    names = [material.name for material in curve.materials]
    summary = {"model": str(model), "ok": True, "stack": str(directory), "layers": len(manifest["layers"]),
               "image": [manifest["image"]["width"], manifest["image"]["height"]], "dpi": manifest["dpi"],
               "volume_mm3": stack_volume_mm3(manifest), "materials": names, "droplet_masks": True,
               "placement": manifest["placement"], "warnings": list(manifest["warnings"]),
               "seconds": {"raster_cpu": times.raster, "encode_cpu": times.encode, "total": times.total}}
    if as_json:
        echo_json(summary)
        return
    click.echo(f"{directory}: {plural(summary['layers'], 'layer')} of {summary['image'][0]} x {summary['image'][1]} px "
               f"at {manifest['dpi'][0]:g} x {manifest['dpi'][1]:g} dpi, volume {summary['volume_mm3']:.1f} mm^3, "
               f"{times.total:.1f} s; intensities as {', '.join(names)}: a solid mask and "
               f"{plural(len(names), 'droplet mask')} per layer")
    sys.stdout.flush()


def slice_ct_with_labels(model: Path, ct, labels, output: Path | None, spec: SliceSpec, force: bool, as_json: bool,
                         materials: MaterialsFile, up: str, smooth: float | None) -> None:
    """One job of a CT and its label map: [labels] print as labels, the [intensity] table's ``within`` labels by
    the CT's values through its curve."""
    from heoslice.material import PartSetting
    from heoslice.pipeline.volume_job import plan_labels, slice_ct_with_labels_to_stack
    from heoslice.volume.model import check_label_keys, labels_named
    from heoslice.volume.intensity import read_curve

    table = materials.data.get("intensity")
    if not isinstance(table, dict) or not isinstance(table.get("within"), list) or not table["within"]:
        raise InputError("--labels: the materials file needs an [intensity] table with a curve and 'within = "
                         "[LABEL, ...]' (the labels printed by the CT's values)")
    curve = read_curve(table, materials.materials, f"{materials.path}: [intensity]")
    settings = dict(materials.labels())
    within = [str(key) for key in table["within"]]
    check_label_keys(labels, [*settings, *within], f"{materials.path}: [labels] and [intensity] within")
    for key in within:
        if key in settings:
            raise InputError(f"{materials.path}: label {key} is in both [labels] and [intensity] within")
        settings[key] = PartSetting(curve.materials[0].name)
    plan = plan_labels(labels, materials.materials, settings, True)
    chosen = {index for key in within for index in labels_named(key, plan.labels)}
    directory = output if output is not None else Path.cwd() / f"{volume_stem(model)}_stack"
    if not as_json:
        echo_warnings(model, [*ct.warnings, *plan.warnings])
        echo_warnings(labels.source, labels.warnings)  # the label map's own notes under its own name
    with progress_bar("slicing", unit="layer") as update:
        manifest, times = slice_ct_with_labels_to_stack(ct, labels, directory, spec, plan, curve, frozenset(chosen),
                                                        up=up, smooth=smooth, force=force, progress=update)
    names = [entry["name"] for entry in manifest["grading"]["materials"]]
    summary = {"model": str(model), "ok": True, "stack": str(directory), "layers": len(manifest["layers"]),
               "image": [manifest["image"]["width"], manifest["image"]["height"]], "dpi": manifest["dpi"],
               "volume_mm3": stack_volume_mm3(manifest), "materials": names, "droplet_masks": True,
               "labels": manifest["labels"], "placement": manifest["placement"],
               "warnings": list(manifest["warnings"]), "seconds": {"total": times.total}}
    if as_json:
        echo_json(summary)
        return
    click.echo(f"{directory}: {plural(summary['layers'], 'layer')} of {summary['image'][0]} x {summary['image'][1]} px, "
               f"volume {summary['volume_mm3']:.1f} mm^3, {times.total:.1f} s; materials {', '.join(names)}")
    sys.stdout.flush()
