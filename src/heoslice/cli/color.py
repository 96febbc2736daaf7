"""``heoslice color``: assign materials by a distribution function and write a coloured PLY."""

from __future__ import annotations

import json
from pathlib import Path

import click

from heoslice.cli.common import echo_warnings, progress_bar
from heoslice.cli.options import (
    FUNCTION_FLAGS,
    apply_scale,
    flags,
    function_from_options,
    function_options,
    option,
    scale_option,
)
from heoslice.errors import InputError
from heoslice.material import (
    FUNCTION_KINDS,
    REFERENCE_KINDS,
    ColorSpec,
    color_mesh,
    default_output,
    material_roles,
    read_materials_file,
    reference_kinds_taking,
    resolve_material,
    same_material,
    write_ply,
)
from heoslice.mesh import load_mesh

#: Library parameters of color_mesh and material_roles -> the options of this command.
COLOR_FLAGS = {**FUNCTION_FLAGS, "reference": "--ref", "at": "--at", "normal": "--normal",
               "direction": "--direction", "surface": "--surface", "r_range": "--range", "max_edge": "--max-edge",
               "start": "--from", "target": "--to"}

EPILOG = """\b
Examples:
  heoslice color vase.ply --func linear          # writes vase_linear.ply beside vase.ply
  heoslice color vase.ply --func sine --periods 3 --to 255,0,0 -o vase_red.ply
  heoslice color vase.ply --func quadratic --alpha 2 --lambda -0.5 --ascii
  heoslice color ball.ply --ref point --at 0,0,0 --func linear --range 0 20
  heoslice color rod.ply --ref axis --direction 1,0,0 --func expr --expr "0.5-0.5*cos(3*pi*r)"
  heoslice color liver.ply --ref surface --surface lesion.ply --to tumour --materials mats.toml
  heoslice color liver.ply --shell-colors 1=255,0,0 --max-edge 0.5
  heoslice color scan_m.ply --scale 1000 --func linear -o scan_mm.ply   # writes mm: slice without --scale
\b
r is the minimum distance of each vertex to the reference, divided by the largest
such distance over the model (or mapped from --range R0 R1 mm to 0..1, clipped).
f(r) is the fraction of the --to material: constant f = lambda (default 1); linear
f = alpha r + lambda (1, 0); quadratic f = alpha r^2 + beta r + lambda (1, 0, 0);
sine f = alpha sin(beta r) + lambda (0.5, 2 pi periods, 0.5); expression: a formula
in r with + - * / **, pi, e and sin cos tan exp log sqrt abs floor min max clip...
Each vertex gets M1 + clip(f, 0, 1) (M2 - M1) as its colour, and f clipped to
[0, 1] as the float vertex property 'material'.
\b
The PLY also records the design (header lines 'heoslice design 1 ...'): M1 and M2 by
name, colour and channel, the reference (a --surface by path and SHA-256), f and the
r normalisation. `slice` follows it: 'material' is the share of the named --to
material, and by default every voxel inside gets f(r) of its own 3-D distance to the
reference (the design's field; `slice --interior contour` carries each layer's
contour material inward instead, the paper's layer-wise distribution).
\b
Materials file (TOML), shared with slice and print:
  [materials.gel]
  color = "#f0f0f0"
  channel = 1
  [materials.cells]
  color = "0,255,0"
  channel = 2
  [shells]
  1 = "cells"
Without one: M1 = 240,240,240 (channel 1) and M2 = 0,255,0 (channel 2).
"""


def parse_vector(name: str, text: str | None) -> tuple[float, float, float] | None:
    """'1,0,0' -> (1.0, 0.0, 0.0); InputError naming the option otherwise."""
    if text is None:
        return None
    parts = text.replace(" ", "").strip("()").split(",")
    try:
        values = tuple(float(part) for part in parts)
    except ValueError:
        values = ()
    if len(values) != 3:
        raise InputError(f"{name}: expected three numbers X,Y,Z, got {text!r}")
    return values  # type: ignore[return-value]


def parse_shell_colors(entries: tuple[str, ...], table) -> dict:
    """('1=tumour', '2=255,0,0') -> {1: Material, 2: Material}."""
    out = {}
    for entry in entries:
        number, sep, spec = entry.partition("=")
        if not sep or not number.strip().isdigit() or not spec.strip():
            raise InputError(f"--shell-colors: expected SHELL=MATERIAL (e.g. 1=tumour or 1=255,0,0), got {entry!r}")
        with option("--shell-colors"):
            out[int(number)] = resolve_material(spec, table)
    return out


@click.command("color", epilog=EPILOG)
@click.argument("model", type=click.Path(path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), default=None,
              help="Output PLY [default: MODEL_FUNC.ply beside MODEL].")
@click.option("--func", "func_kind", default=None, metavar="|".join(FUNCTION_KINDS),
              help="Distribution function [default: linear; expression when --expr is given].")
@function_options
@click.option("--ref", "ref_kind", default="plane", show_default=True, metavar="|".join(REFERENCE_KINDS),
              help="Reference feature the distance is measured to.")
@click.option("--at", default=None, metavar="X,Y,Z",
              help="Point of the plane / axis, or the point [default: lowest point for a plane, "
                   "bounding-box centre otherwise], mm.")
@click.option("--normal", default=None, metavar="X,Y,Z", help="Plane normal [default: 0,0,1].")
@click.option("--direction", default=None, metavar="X,Y,Z", help="Axis direction [default: 0,0,1].")
@click.option("--surface", "surface_path", type=click.Path(path_type=Path), default=None,
              help="Mesh whose surface is the reference (with --ref surface).")
@click.option("--range", "r_range", type=float, nargs=2, default=None, metavar="R0 R1",
              help="Distances (mm) mapped to r = 0 and r = 1 [default: 0 and the largest distance].")
@click.option("--from", "m1_text", default=None, metavar="MATERIAL",
              help="M1 (f <= 0): a material name, #hex or r,g,b [default: first material, or the next one when --to "
                   "names the first].")
@click.option("--to", "m2_text", default=None, metavar="MATERIAL",
              help="M2 (f >= 1): a material name, #hex or r,g,b [default: second material, or the first one when "
                   "--from names the second].")
@click.option("--materials", "materials_file", type=click.Path(path_type=Path), default=None,
              help="Materials file (TOML) [default: built-in M1, M2].")
@click.option("--max-edge", type=float, default=None, metavar="MM",
              help="Subdivide first so that no edge is longer than this.")
@click.option("--shell-colors", "shell_colors", multiple=True, metavar="SHELL=MATERIAL",
              help="Colour a whole shell with a material (repeatable; shells as numbered by heoslice info).")
@scale_option
@click.option("--ascii", "ascii_ply", is_flag=True, help="Write an ASCII PLY [default: binary].")
@click.option("--force", is_flag=True, help="Overwrite an existing output file.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary instead of text.")
def color(model: Path, output: Path | None, func_kind: str | None, alpha, beta, lam, periods, expression,
          ref_kind: str, at, normal, direction, surface_path, r_range, m1_text, m2_text, materials_file,
          max_edge, shell_colors, scale: float, ascii_ply: bool, force: bool, as_json: bool) -> None:
    """Colour MODEL's vertices by a material distribution function of the distance to a reference.

    The paper's Z-axis modelling (eq. 1-5, Fig. 2): the default reference is the X-Y
    plane through the model's lowest point, so `--func linear` grades from M1 at the
    bottom to M2 at the top.

    With --scale the model (and the --surface mesh) are scaled first: --at, --range and
    --max-edge are in mm of the scaled model, and the PLY is written in mm (slice it without
    --scale).
    """
    if func_kind is None:
        func_kind = "expression" if expression is not None else "linear"
    function = function_from_options("--func", func_kind, alpha, beta, lam, periods, expression)
    if ref_kind not in REFERENCE_KINDS:
        raise InputError(f"--ref: unknown reference {ref_kind!r} (choose from {', '.join(REFERENCE_KINDS)})")
    point = parse_vector("--at", at)
    plane_normal = parse_vector("--normal", normal)
    axis_direction = parse_vector("--direction", direction)
    for name, value in (("at", point), ("normal", plane_normal), ("direction", axis_direction),
                        ("surface", surface_path)):
        kinds = reference_kinds_taking(name)
        if value is not None and ref_kind not in kinds:
            raise InputError(f"--{name}: only used with --ref {' or '.join(kinds)}, not --ref {ref_kind}")
    if ref_kind == "surface" and surface_path is None:
        raise InputError("--surface: --ref surface needs the reference mesh (--surface PATH); every vertex "
                         "of the model lies on its own surface, at distance 0")
    if r_range is not None and not r_range[1] > r_range[0]:
        raise InputError(f"--range: {r_range[0]:g} {r_range[1]:g} mm is of zero or negative width (need R0 < R1)")
    if max_edge is not None and not max_edge > 0:
        raise InputError(f"--max-edge: must be a positive length in mm, got {max_edge:g}")
    with option("--materials"):
        materials = read_materials_file(materials_file)
        table, file_shells = materials.materials, materials.shells()
    with flags(COLOR_FLAGS):
        roles = material_roles(table, start=m1_text, target=m2_text)
    if roles.m2 is None:
        raise InputError(f"--to: {materials_file} defines one material: name the target material (M2)")
    if same_material(roles.m1, roles.m2):  # a role named alone, and the table has no other material
        raise InputError(f"--from, --to: both are {roles.m1.name!r}; a grade needs two materials (name the other)")
    typed_shells = parse_shell_colors(shell_colors, table)
    shells = {**file_shells, **typed_shells}
    if materials_file is not None:  # slice settles the design against the same file: a colour outside it is refused
        from heoslice.material.design import settle_material

        settled = [("--from", "start", roles.m1), ("--to", "target", roles.m2)]
        settled += [("--shell-colors", f"shell {number}", material) for number, material in typed_shells.items()]
        for flag, role, material in settled:
            with flags({str(model): flag}):
                settle_material(material, table, role, str(materials_file), str(model))

    mesh = apply_scale(load_mesh(model), scale)
    surface = surface_path
    if surface_path is not None and scale != 1.0:
        with option("--surface"):
            surface = apply_scale(load_mesh(surface_path), scale)
    if not as_json:
        echo_warnings(model, mesh.warnings)
    spec = ColorSpec(function=function, reference=ref_kind, at=point, normal=plane_normal,
                     direction=axis_direction, surface=surface, surface_scale=scale,
                     r_range=None if r_range is None else (float(r_range[0]), float(r_range[1])),
                     m1=roles.m1, m2=roles.m2, max_edge=max_edge, shell_materials=tuple(sorted(shells.items())))
    range_flag = "--range" if spec.r_range is not None else f"--ref {ref_kind}"
    mapping = {**COLOR_FLAGS, "shell_materials": "--shell-colors" if shell_colors else "--materials",
               "r_range": range_flag}
    with progress_bar("colouring", unit="vertices", enabled=not as_json) as progress, flags(mapping):
        colored = color_mesh(mesh, spec, progress)
    target = output if output is not None else default_output(model, function)
    write_ply(target, colored, ascii=ascii_ply, force=force,
              inputs=tuple(p for p in (model, surface_path, materials_file) if p is not None))
    f = colored.material
    if as_json:
        click.echo(json.dumps({
            "model": str(model), "ok": True, "output": str(target), "vertices": len(colored.vertices),
            "triangles": len(colored.faces), "function": function.describe(), "reference": colored.reference.describe(),
            "r": [float(colored.r.min()), float(colored.r.max())], "f": [float(f.min()), float(f.max())],
            "from": roles.m1.record(), "to": roles.m2.record(),
            "shells": {str(n): m.record() for n, m in spec.shell_materials}, "warnings": list(mesh.warnings),
        }))
        return
    click.echo(f"{target}: {len(colored.vertices)} vertices, {len(colored.faces)} triangles; "
               f"{function.describe()}; reference {colored.reference.describe()}; "
               f"r {colored.r.min():.3g}..{colored.r.max():.3g}, f {f.min():.3g}..{f.max():.3g}; "
               f"{roles.m1.name} -> {roles.m2.name}"
               + (f"; shells {', '.join(f'{n}={m.name}' for n, m in spec.shell_materials)}" if shells else ""))
