"""Can this stack print: the one rule ``verify``, ``print`` (and ``--dry-run``), ``export --format voxel-print``
and ``slice`` (as a warning) apply to a checked manifest.

A stack prints when it carries one material per pixel (a 1-bit solid mask, with droplet masks when it holds
several materials) and at least one solid pixel. An RGBA stack (``slice --rgba``) is a preview: its pixels
carry blended display colours, not droplets. A stack whose every layer is empty would run the printer for
nothing (a mesh of loose triangles slices to 0 mm^3).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from heoslice.errors import InputError


@dataclass(frozen=True, slots=True)
class PrintRule:
    """One reason a stack cannot print: ``refuses(manifest)`` says whether it applies, ``problem`` what is wrong
    and ``remedy`` what to do, both for a one-line message; ``slice_warns``: ``slice`` warns when it writes such
    a stack (not when the user asked for it, as with --rgba)."""

    name: str
    refuses: Callable[[dict], bool]
    problem: str
    remedy: str
    slice_warns: bool


def _preview_only(manifest: dict) -> bool:
    return manifest["image"].get("mode", "1") == "RGBA"


def _every_layer_empty(manifest: dict) -> bool:
    return not any(entry["solid_pixels"] for entry in manifest["layers"])


#: The rules, in the order they are reported (the first that applies is the refusal).
PRINT_RULES = (
    PrintRule("preview-only", _preview_only,
              "a preview-only RGBA stack (sliced with --rgba): its pixels carry blended display colours, "
              "not droplet masks", "slice the model again without --rgba to print it", slice_warns=False),
    PrintRule("empty", _every_layer_empty,
              "every layer is empty (0 solid pixels): there is nothing to print",
              "check the model with 'heoslice info' (a closed, watertight surface slices to a solid) and the "
              "layer height",
              slice_warns=True),
)


def print_refusal(manifest: dict) -> PrintRule | None:
    """The first rule of PRINT_RULES that refuses a structurally checked manifest, or None when it can print."""
    return next((rule for rule in PRINT_RULES if rule.refuses(manifest)), None)


def refusal_line(rule: PrintRule, label: object) -> str:
    """The one-line message of a refusal naming the stack ``label``: 'STACK: cannot print: PROBLEM; REMEDY'."""
    return f"{label}: cannot print: {rule.problem}; {rule.remedy}"


def check_printable(manifest: dict, label: object) -> None:
    """Raise InputError (exit 2, one line naming ``label``) when the stack of ``manifest`` cannot print."""
    rule = print_refusal(manifest)
    if rule is not None:
        raise InputError(refusal_line(rule, label))
