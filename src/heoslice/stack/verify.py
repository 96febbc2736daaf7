"""Verifying a stack: the manifest, every listed file (inside, present, sha256, layout, solid pixels),
droplet masks against their layer and their printer channels, layer heights, and no unlisted layer
files."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from heoslice.errors import VerifyError
from heoslice.stack.manifest import LAYER_PATTERN, MANIFEST, MASK_MODE, layer_height_problems, mask_channels
from heoslice.stack.read import (decode_checked, decode_mask, read_checked, read_layer_mask, read_manifest,
                                 resolve_inside)
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



def _layer_file_problem(path: Path, name: str, digest: str, solid: int | None, manifest: dict,
                        mode: str | None, check_pixels: bool) -> str | None:
    """Problem of one listed image file (layout, size, hash, solid pixel count), or None."""
    try:
        data = read_checked(path, name, digest, manifest, mode)
        if check_pixels and solid is not None:
            found = decode_checked(data, name, manifest, mode, None)
            if found != solid:
                return f"{name}: has {found} solid pixels, manifest says {solid}"
    except VerifyError as err:
        return str(err)
    return None



def _channel_problems(directory: Path, manifest: dict, index: int) -> list[str]:
    """Droplet masks against their layer: every solid pixel in exactly one mask, empty pixels in none; a line
    per kind of fault naming its first pixel (:func:`heoslice.stack.report.mask_faults`)."""
    entry = manifest["layers"][index]
    solid = np.packbits(read_layer_mask(directory, manifest, index), axis=-1)
    masks = np.stack([np.packbits(decode_mask(resolve_inside(directory, channel["file"]), manifest,
                                              sha256=channel["sha256"], mode=MASK_MODE), axis=-1)
                      for channel in entry["channels"]])
    return fault_lines(index, mask_faults(solid, masks), manifest)


def verify_stack(directory: Path, *, check_pixels: bool = True) -> StackReport:
    """Check a stack: manifest, every listed file (inside, present, sha256, size, dpi, solid pixels), extras.

    Returns a report listing every problem found, one line each.
    """
    directory = Path(directory)
    try:
        manifest = read_manifest(directory)
    except VerifyError as err:
        return StackReport(directory, (str(err),))
    problems: list[str] = []
    listed: dict[Path, str] = {}
    mode = manifest["image"].get("mode", "1")
    for entry in manifest["layers"]:
        index = entry["index"]
        files = [(entry["file"], entry["sha256"], entry["solid_pixels"], mode)]
        files += [(channel["file"], channel["sha256"], channel.get("solid_pixels"), MASK_MODE)
                  for channel in entry.get("channels", [])]
        for name, digest, solid, file_mode in files:
            path = resolve_inside(directory, name)
            if path is None:
                problems.append(f"layer {index}: file {name!r} lies outside the stack")
                continue
            if path in listed:
                problems.append(f"layer {index}: {name} is listed twice (also by {listed[path]})")
                continue
            listed[path] = f"layer {index}"
            if not path.is_file():
                problems.append(f"layer {index}: {name} is {'not a regular file' if path.exists() else 'missing'}")
                continue
            problem = _layer_file_problem(path, name, digest, solid, manifest, file_mode, check_pixels)
            if problem:
                problems.append(f"layer {index}: {problem}")
        if entry.get("channels") and check_pixels and not any(p.startswith(f"layer {index}:") for p in problems):
            problems += _channel_problems(directory, manifest, index)
    try:
        mask_channels(manifest, MANIFEST)
    except VerifyError as err:
        problems.append(str(err))
    z_min, z_max = manifest["z_range_mm"]
    problems += layer_height_problems(manifest, z_min, z_max, "the manifest's")
    root = directory.resolve()
    names = {path.name for path in listed if path.parent == root}
    for entry in sorted(directory.iterdir()):
        if LAYER_PATTERN.match(entry.name) and entry.name not in names:
            problems.append(f"{entry.name}: layer file not listed in the manifest")
    return StackReport(directory, tuple(problems), manifest)


def load_verified(directory: Path, *, check_pixels: bool = True) -> dict:
    """The manifest of a stack that passes :func:`verify_stack`; raise VerifyError with its problems otherwise.

    ``check_pixels`` False (preview, which decodes what it draws) skips decoding: every file is still checked
    present, regular, inside, of the manifest's layout and mode, and of its sha256."""
    report = verify_stack(directory, check_pixels=check_pixels)
    if not report.ok:
        more = f" (and {len(report.problems) - 1} more problem(s))" if len(report.problems) > 1 else ""
        first = report.problems[0]
        named = first if first.startswith((f"{directory}:", f"{directory}/")) else f"{directory}: {first}"
        raise VerifyError(f"{named}{more}")
    return report.manifest


