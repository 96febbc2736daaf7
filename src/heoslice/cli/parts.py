"""``heoslice slice`` of a multi-part job: several models (or a 3MF's objects) into one stack, each part's pixels
carrying its part's material (:mod:`heoslice.pipeline.parts`). The command line only parses and reports."""

from __future__ import annotations

from pathlib import Path

import click

from heoslice.cli.options import option
from heoslice.errors import InputError
from heoslice.material import MaterialsFile, PartSetting, table_material

#: What a multi-part job refuses, and why (one line each): the option -> its line.
REFUSALS = {
    "--grade": "--grade: a multi-part job is not graded (slice a part on its own to grade it)",
    "--interior": "--interior: each part of a multi-part job is one material (it applies to a coloured model)",
    "--rgba": "--rgba: a multi-part job is a print job with a droplet mask per material (see it with heoslice "
              "preview STACK)",
}


def is_parts_job(models: tuple[Path, ...], parts_flag: bool, part_options: tuple[str, ...],
                 materials: MaterialsFile) -> bool:
    """Whether the call is one multi-part job: --parts, a --part option, a 3MF among the models, or a [parts]
    table in the materials file. Otherwise every model is its own stack, as before."""
    if parts_flag or part_options or any(str(model).lower().endswith(".3mf") for model in models):
        return True
    with option("--materials"):
        return bool(materials.parts())


def parse_part_options(part_options: tuple[str, ...], table: dict) -> dict[str, str]:
    """{part name: material name} of the --part NAME=MATERIAL options, each material one of ``table``."""
    chosen = {}
    for text in part_options:
        name, equals, material = text.partition("=")
        if not (equals and name.strip() and material.strip()):
            raise InputError(f"--part: expected NAME=MATERIAL (e.g. lesion=M2), got {text!r}")
        if table_material(material.strip(), table) is None:
            raise InputError(f"--part {text}: unknown material {material.strip()!r} (materials: {', '.join(table)})")
        chosen[name.strip()] = material.strip()
    return chosen


def part_settings(materials: MaterialsFile, part_options: tuple[str, ...], part_names: list[str]
                  ) -> tuple[dict, dict[str, PartSetting]]:
    """(materials table, {part name: setting}): the materials file's [parts], with --part options overriding
    their material (a file's priority stays). A name that is no part of the job is refused, naming where it
    was given."""
    table = materials.materials
    with option("--materials"):
        settings = materials.parts()
    given = parse_part_options(part_options, table)
    shown = ", ".join(dict.fromkeys(part_names))
    for name in settings:
        if name not in part_names:
            raise InputError(f"{materials.path}: [parts] {name}: no part of this job has that name "
                             f"(its parts: {shown})")
    for name in given:
        if name not in part_names:
            raise InputError(f"--part {name}=...: no part of this job has that name (its parts: {shown})")
    for name, material in given.items():
        settings[name] = PartSetting(material, settings[name].priority if name in settings else None)
    return table, settings


def report_parts(directory: Path, manifest: dict) -> None:
    """One line naming each part's material, in rank order (the first wins where parts overlap), and the
    droplet masks written."""
    ranked = sorted(manifest.get("parts", []), key=lambda part: part["rank"])
    listed = ", ".join(f"{part['name']} -> {part['material']}" for part in ranked)
    materials = [m["name"] for m in (manifest.get("grading") or {}).get("materials", [])]
    masks = f"droplet masks {', '.join(materials)}" if materials else "one material: the solid mask only"
    click.echo(f"{directory}: parts (first wins overlaps) {listed}; {masks}")
