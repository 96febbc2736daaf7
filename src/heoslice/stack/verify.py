"""Verifying a stack: the manifest, every listed file (inside, present, sha256, layout, solid pixels),
droplet masks against their layer and their printer channels, layer heights, and no unlisted layer
files."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path


from heoslice.errors import VerifyError
from heoslice.stack.manifest import LAYER_PATTERN, MANIFEST, MASK_MODE, layer_height_problems, mask_channels
from heoslice.stack.packed import Bits, count_bits, read_layer_file, solid_bits
from heoslice.stack.read import read_manifest, resolve_inside
from heoslice.stack.report import fault_lines, mask_faults


@dataclass(frozen=True)
class StackReport:
    """Outcome of :func:`verify_stack`: ``problems`` (one line each; empty when clean) and the manifest."""

    directory: Path
    problems: tuple[str, ...]
    manifest: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.problems



#: One listed file of a layer to check: (path, name, sha256, solid pixel count or None, image mode or None).
FileCheck = tuple[Path, str, str, int | None, str | None]


def _file_problem(check: FileCheck, manifest: dict, check_pixels: bool) -> tuple[str | None, Bits | None]:
    """(problem of one listed image file or None, its solid pixels as packed rows when decoded): layout, size,
    hash, and the solid pixel count (the file read and decoded once)."""
    path, name, digest, solid, mode = check
    try:
        layer = read_layer_file(path, name, digest, manifest, mode)
        if not check_pixels:
            return None, None
        bits = solid_bits(layer, manifest["mask"] == "alpha" and mode is not None)
        found = count_bits(bits.rows[bits.span[0]:bits.span[1]])
        if solid is not None and found != solid:
            return f"{name}: has {found} solid pixels, manifest says {solid}", bits
        return None, bits
    except VerifyError as err:
        return str(err), None


def _coverage_problems(index: int, solid: Bits, masks: list[Bits], manifest: dict) -> list[str]:
    """Droplet masks against their layer: every solid pixel in exactly one mask, empty pixels in none, over the
    rows where any of them has a set bit; a line per kind of fault naming its first pixel
    (:func:`heoslice.stack.report.mask_faults`)."""
    first = min(bits.span[0] for bits in [solid, *masks])
    stop = max(bits.span[1] for bits in [solid, *masks])
    faults = mask_faults(solid.rows[first:stop], [mask.rows[first:stop] for mask in masks], row_offset=first)
    return fault_lines(index, faults, manifest)


def layer_problems(index: int, plan: list, manifest: dict, check_pixels: bool) -> list[str]:
    """Problems of layer ``index``, one line each: ``plan`` lists its files in order, each a problem line
    already found (str) or a :data:`FileCheck`; the droplet masks are checked against the layer when every
    file passed. Each file is read, hashed and decoded once."""
    problems, bits = [], []
    for item in plan:
        if isinstance(item, str):
            problems.append(item)
            continue
        problem, decoded = _file_problem(item, manifest, check_pixels)
        if problem:
            problems.append(f"layer {index}: {problem}")
        bits.append(decoded)
    channels = manifest["layers"][index].get("channels")
    if channels and check_pixels and not problems:
        problems += _coverage_problems(index, bits[0], bits[1:], manifest)
    return problems


#: ``layer_map(function, items)``: function(item) for each item, yielded in order. The builtin map checks
#: the layers one after another; a later stage passes :func:`heoslice.pipeline.parallel.ordered_map` to
#: spread them over the cores (the stack stage holds no process machinery).
LayerMap = Callable[[Callable, Iterable], Iterable]


def verify_stack(directory: Path, *, check_pixels: bool = True, layer_map: LayerMap = map,
                 progress: Callable[[int, int], None] | None = None) -> StackReport:
    """Check a stack: manifest, every listed file (inside, present, sha256, size, dpi, solid pixels), extras.

    Returns a report listing every problem found, one line each. The layers are checked through
    ``layer_map`` (:data:`LayerMap`), each file read and decoded once; ``progress(done, total)`` is called
    as each layer's check is done.
    """
    directory = Path(directory)
    try:
        manifest = read_manifest(directory)
    except VerifyError as err:
        return StackReport(directory, (str(err),))
    problems: list[str] = []
    listed: dict[Path, str] = {}
    mode = manifest["image"].get("mode", "1")
    root = directory.resolve()
    plans = []
    for entry in manifest["layers"]:
        index = entry["index"]
        files = [(entry["file"], entry["sha256"], entry["solid_pixels"], mode)]
        files += [(channel["file"], channel["sha256"], channel.get("solid_pixels"), MASK_MODE)
                  for channel in entry.get("channels", [])]
        plan: list = []
        for name, digest, solid, file_mode in files:
            path = resolve_inside(root, name, resolved=True)
            if path is None:
                plan.append(f"layer {index}: file {name!r} lies outside the stack")
                continue
            if path in listed:
                plan.append(f"layer {index}: {name} is listed twice (also by {listed[path]})")
                continue
            listed[path] = f"layer {index}"
            if not path.is_file():
                plan.append(f"layer {index}: {name} is {'not a regular file' if path.exists() else 'missing'}")
                continue
            plan.append((path, name, digest, solid, file_mode))
        plans.append(plan)
    total = len(plans)
    for done, found in enumerate(layer_map(lambda index: layer_problems(index, plans[index], manifest,
                                                                        check_pixels),
                                           range(total)), start=1):
        problems += found
        if progress is not None:
            progress(done, total)
    try:
        mask_channels(manifest, MANIFEST)
    except VerifyError as err:
        problems.append(str(err))
    z_min, z_max = manifest["z_range_mm"]
    problems += layer_height_problems(manifest, z_min, z_max, "the manifest's")
    names = {path.name for path in listed if path.parent == root}
    for entry in sorted(os.listdir(directory)):
        if LAYER_PATTERN.match(entry) and entry not in names:
            problems.append(f"{entry}: layer file not listed in the manifest")
    return StackReport(directory, tuple(problems), manifest)


def load_verified(directory: Path, progress: Callable[[int, int], None] | None = None,
                  layer_map: LayerMap = map, *, check_pixels: bool = True) -> dict:
    """The manifest of a stack that passes :func:`verify_stack` (``progress`` and ``layer_map`` passed on);
    raise VerifyError with its problems otherwise.

    ``check_pixels`` False (preview, which decodes what it draws) skips decoding: every file is still checked
    present, regular, inside, of the manifest's layout and mode, and of its sha256."""
    report = verify_stack(directory, progress=progress, layer_map=layer_map, check_pixels=check_pixels)
    if not report.ok:
        more = f" (and {len(report.problems) - 1} more problem(s))" if len(report.problems) > 1 else ""
        first = report.problems[0]
        named = first if first.startswith((f"{directory}:", f"{directory}/")) else f"{directory}: {first}"
        raise VerifyError(f"{named}{more}")
    return report.manifest


