"""Verifying a stack: the manifest, every listed file (inside, present, sha256, layout, solid pixels),
droplet masks against their layer and their printer channels, layer heights, and no unlisted layer
files. The same checks serve a reader in one pass: the stack as a whole first (:func:`open_verified`), then
each layer as it is read (:func:`verified_layer`; :func:`check_unread_layers` for the layers it skips)."""

from __future__ import annotations

import os
from collections.abc import Callable, Collection, Iterable
from dataclasses import dataclass, field
from pathlib import Path


from heoslice.errors import VerifyError
from heoslice.stack.manifest import LAYER_PATTERN, MANIFEST, MASK_MODE, layer_height_problems, mask_channels
from heoslice.stack.packed import (Bits, InflatedStrips, partition_counts, read_layer_file,
                                   solid_bits)
from heoslice.stack.read import read_manifest, regular_files, resolve_inside
from heoslice.stack.report import fault_lines, mask_faults


@dataclass(frozen=True)
class StackReport:
    """Outcome of :func:`verify_stack`: ``problems`` (one line each; empty when clean), the manifest, and what its
    ``also`` made of the layers it was given (layer index -> its value)."""

    directory: Path
    problems: tuple[str, ...]
    manifest: dict = field(default_factory=dict)
    also: dict = field(default_factory=dict, repr=False)

    @property
    def ok(self) -> bool:
        return not self.problems



#: One listed file of a layer to check: (its resolved path as text, name, sha256, solid pixel count or None, image
#: mode or None).
FileCheck = tuple[str, str, str, int | None, str | None]


def _file_bits(check: FileCheck, manifest: dict, check_pixels: bool, inflated: InflatedStrips,
               decoded: list[tuple[bytes, str | None, bool, Bits]]) -> tuple[str | None, Bits | None]:
    """(problem of one listed image file or None, its solid pixels as packed rows when decoded): layout, size
    and hash checked, the file read and decoded once (a strip already inflated from another file of the layer,
    in ``inflated``, copied; a file whose bytes and reading are another's, in ``decoded``, given its Bits)."""
    path, name, digest, _, mode = check
    try:
        layer = read_layer_file(path, name, digest, manifest, mode)
        if not check_pixels:
            return None, None
        alpha = manifest["mask"] == "alpha" and mode is not None
        for data, its_mode, its_alpha, bits in decoded:
            if (its_mode, its_alpha) == (mode, alpha) and data == layer.data:
                return None, bits
        bits = solid_bits(layer, alpha, inflated=inflated)
        decoded.append((layer.data, mode, alpha, bits))
        return None, bits
    except VerifyError as err:
        return str(err), None


def _rows_of(bits: list[Bits]) -> tuple[int, int]:
    """The rows (first, stop) holding every set bit of a layer's files."""
    return min(b.span[0] for b in bits), max(b.span[1] for b in bits)


def layer_check(index: int, plan: list, manifest: dict, check_pixels: bool) -> tuple[list[str], list[Bits | None]]:
    """(problems of layer ``index``, one line each; each listed file's :class:`Bits`, None where not decoded):
    ``plan`` lists its files in order, each a problem line already found (str) or a :data:`FileCheck`. Each
    file is read, hashed and decoded once; its solid pixels are counted against the manifest, and the
    droplet masks checked against the layer when every file passed (a solid pixel in exactly one mask, none
    outside), counted and checked in one pass per file (:func:`heoslice.stack.packed.partition_counts`)."""
    found: list[tuple[str | None, FileCheck | None, Bits | None]] = []  # per listed file: problem, check, bits
    inflated: InflatedStrips = {}
    known: list[tuple[bytes, str | None, bool, Bits]] = []
    for item in plan:
        if isinstance(item, str):
            found.append((item, None, None))
            continue
        problem, decoded = _file_bits(item, manifest, check_pixels, inflated, known)
        found.append((f"layer {index}: {problem}" if problem else None, item, decoded))
    bits = [decoded for _, check, decoded in found if check is not None]
    decoded = [b for b in bits if b is not None]
    channels = manifest["layers"][index].get("channels")
    partitioned = False
    if channels and check_pixels and len(decoded) == len(plan) > 1:
        counts, partitioned = partition_counts(decoded[0], decoded[1:])
    else:
        from heoslice.layers.bits import count_solid

        counts = [count_solid(b.rows[b.span[0]:b.span[1]]) for b in decoded]
    counted = iter(counts)
    lines: list[str] = []
    for problem, check, decoded_bits in found:
        count = next(counted) if decoded_bits is not None else None
        if problem:
            lines.append(problem)
        elif count is not None and check[3] is not None and count != check[3]:
            lines.append(f"layer {index}: {check[1]}: has {count} solid pixels, manifest says {check[3]}")
    if channels and check_pixels and not lines and not partitioned:
        first, stop = _rows_of(decoded)
        faults = mask_faults(decoded[0].rows[first:stop], [b.rows[first:stop] for b in decoded[1:]],
                             row_offset=first, clean_checked=True)
        lines += fault_lines(index, faults, manifest)
    return lines, bits


def layer_problems(index: int, plan: list, manifest: dict, check_pixels: bool) -> list[str]:
    """Problems of layer ``index``, one line each (:func:`layer_check`)."""
    return layer_check(index, plan, manifest, check_pixels)[0]


#: ``layer_map(function, items)``: function(item) for each item, yielded in order. The builtin map checks
#: the layers one after another; a later stage passes :func:`heoslice.pipeline.parallel.ordered_map` to
#: spread them over the cores (the stack stage holds no process machinery).
LayerMap = Callable[[Callable, Iterable], Iterable]


@dataclass(frozen=True)
class StackPlan:
    """A stack read for checking: its manifest, per layer the :func:`layer_check` plan of its files, and the
    problems of the stack as a whole (masks' channels, layer heights, unlisted layer files), one line each."""

    directory: Path
    manifest: dict
    plans: tuple[list, ...]
    problems: tuple[str, ...]


def plan_stack(directory: Path) -> StackPlan:
    """The :class:`StackPlan` of the stack in ``directory``: manifest parsed and bounded (VerifyError when it
    cannot be read), each listed file resolved inside the stack and listed once."""
    directory = Path(directory)
    manifest = read_manifest(directory)
    listed: dict[str, str] = {}  # resolved path -> the layer listing it
    mode = manifest["image"].get("mode", "1")
    root = directory.resolve()
    root_text = str(root)
    regular = regular_files(root)
    plans = []
    for entry in manifest["layers"]:
        index = entry["index"]
        files = [(entry["file"], entry["sha256"], entry["solid_pixels"], mode)]
        files += [(channel["file"], channel["sha256"], channel.get("solid_pixels"), MASK_MODE)
                  for channel in entry.get("channels", [])]
        plan: list = []
        for name, digest, solid, file_mode in files:
            plain = isinstance(name, str) and name in regular  # a regular file of the folder: no stat needed
            if plain:  # joined as text: a Path a file made this loop the parent's slowest part
                path = os.path.join(root_text, name)
            else:
                inside = resolve_inside(root, name, resolved=True)
                path = None if inside is None else str(inside)
            if path is None:
                plan.append(f"layer {index}: file {name!r} lies outside the stack")
                continue
            if path in listed:
                plan.append(f"layer {index}: {name} is listed twice (also by {listed[path]})")
                continue
            listed[path] = f"layer {index}"
            if not plain and not os.path.isfile(path):
                plan.append(f"layer {index}: {name} is {'not a regular file' if os.path.exists(path) else 'missing'}")
                continue
            plan.append((path, name, digest, solid, file_mode))
        plans.append(plan)
    problems: list[str] = []
    try:
        mask_channels(manifest, MANIFEST)
    except VerifyError as err:
        problems.append(str(err))
    z_min, z_max = manifest["z_range_mm"]
    problems += layer_height_problems(manifest, z_min, z_max, "the manifest's")
    names = {os.path.basename(path) for path in listed if os.path.dirname(path) == root_text}
    for entry in sorted(os.listdir(directory)):
        if LAYER_PATTERN.match(entry) and entry not in names:
            problems.append(f"{entry}: layer file not listed in the manifest")
    return StackPlan(directory, manifest, tuple(plans), tuple(problems))


#: ``also(manifest)``: the work a reader of a stack wants done on some of its layers while they are checked, or
#: None: (the layers, ``work(index, bits)``), called on each of those layers that passed its check with its
#: files' :class:`Bits` (the layer's own, then its droplet masks' in manifest order), in the process that checked
#: it; what it returns goes back (keep it small). The manifest is not yet verified: only a layer's bits are.
AlsoWork = Callable[[dict], tuple[Collection[int], Callable[[int, list[Bits]], object]] | None]


def verify_stack(directory: Path, *, check_pixels: bool = True, layer_map: LayerMap = map,
                 progress: Callable[[int, int], None] | None = None, also: AlsoWork | None = None) -> StackReport:
    """Check a stack: manifest, every listed file (inside, present, sha256, size, dpi, solid pixels), extras.

    Returns a report listing every problem found, one line each. The layers are checked through
    ``layer_map`` (:data:`LayerMap`), each file read and decoded once; ``progress(done, total)`` is called
    as each layer's check is done. ``also`` (:data:`AlsoWork`, with ``check_pixels``) works on the decoded
    layers it names in the same pass, its results in the report's ``also``, so that a reader needs no
    second reading of them.
    """
    directory = Path(directory)
    try:
        plan = plan_stack(directory)
    except VerifyError as err:
        return StackReport(directory, (str(err),))
    asked = also(plan.manifest) if also is not None and check_pixels else None
    layers, work = (set(asked[0]), asked[1]) if asked is not None else ((), None)

    def check(index: int) -> tuple[list[str], object]:
        if index not in layers:
            return layer_problems(index, plan.plans[index], plan.manifest, check_pixels), None
        found, bits = layer_check(index, plan.plans[index], plan.manifest, check_pixels)
        return found, (None if found else work(index, bits))

    problems: list[str] = []
    worked = {}
    total = len(plan.plans)
    for done, (found, result) in enumerate(layer_map(check, range(total)), start=1):
        problems += found
        if result is not None:
            worked[done - 1] = result
        if progress is not None:
            progress(done, total)
    return StackReport(directory, tuple(problems) + plan.problems, plan.manifest, worked)


def refusal(directory: Path, problems: tuple[str, ...] | list[str]) -> VerifyError:
    """The one-line error of a stack with ``problems``: the first, named by the stack, and how many more."""
    more = f" (and {len(problems) - 1} more problem(s))" if len(problems) > 1 else ""
    first = problems[0]
    named = first if first.startswith((f"{directory}:", f"{directory}/")) else f"{directory}: {first}"
    return VerifyError(f"{named}{more}")


def open_verified(directory: Path) -> StackPlan:
    """The :class:`StackPlan` of a stack for reading it while checking it layer by layer
    (:func:`verified_layer`); VerifyError (:func:`refusal`) when it has a problem as a whole or a listed file
    is known bad without reading it (missing, outside the stack, listed twice), before anything is written."""
    plan = plan_stack(directory)
    listed = [line for plan_of in plan.plans for line in plan_of if isinstance(line, str)]
    if listed or plan.problems:  # the layers' problems first, as verify lists them
        raise refusal(Path(directory), listed + list(plan.problems))
    return plan


def verified_layer(plan: StackPlan, index: int) -> tuple[Bits, list[Bits]]:
    """Layer ``index`` of a stack opened by :func:`open_verified`, checked as :func:`verify_stack` checks it
    (VerifyError, :func:`refusal`, on a problem): (its solid pixels, its droplet masks' in manifest order),
    each file read and decoded once. An export that writes as it checks calls it for every layer."""
    problems, bits = layer_check(index, plan.plans[index], plan.manifest, True)
    if problems:
        raise refusal(plan.directory, problems)
    return bits[0], bits[1:]


def check_unread_layers(plan: StackPlan, read: Iterable[int], layer_map: LayerMap = map) -> None:
    """Refuse (VerifyError, :func:`refusal`) a stack opened by :func:`open_verified` that a reader of only the
    layers ``read`` (which it reads with their checks: inside, layout, sha256) must not draw: a file problem
    :func:`plan_stack` found in any layer, or of any other layer's files, checked without decoding (present,
    regular, inside, layout and mode, sha256), through ``layer_map``."""
    read = set(read)
    unread = [index for index in range(len(plan.plans)) if index not in read]
    found = {index: [line for line in plan.plans[index] if isinstance(line, str)] for index in read}
    found.update(zip(unread, layer_map(lambda index: layer_problems(index, plan.plans[index], plan.manifest, False),
                                       unread)))
    problems = [line for index in sorted(found) for line in found[index]]
    if problems:
        raise refusal(plan.directory, problems)


def load_verified(directory: Path, progress: Callable[[int, int], None] | None = None,
                  layer_map: LayerMap = map, *, check_pixels: bool = True) -> dict:
    """The manifest of a stack that passes :func:`verify_stack` (``progress`` and ``layer_map`` passed on);
    raise VerifyError with its problems otherwise.

    ``check_pixels`` False skips decoding: every file is still checked present, regular, inside, of the
    manifest's layout and mode, and of its sha256."""
    report = verify_stack(directory, progress=progress, layer_map=layer_map, check_pixels=check_pixels)
    if not report.ok:
        raise refusal(Path(directory), report.problems)
    return report.manifest


