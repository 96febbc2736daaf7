"""Each halftoning method (``slice --halftone``) on the same graded layer: a picture for the README.

Usage: python examples/halftones.py [OUT.png] [--width 480] [--height 120] [--scale 2]

The layer is a 600 dpi strip graded linearly from M1 (left) to M2 (right), as eq. 1 grades a
sub-region's mix towards the target; each method's droplet masks
(:func:`heoslice.grading.halftone.halftone`, layer 5, error diffusion after layers 0..4 so that it
carries their error) are drawn in the materials' display colours, one strip per method, each pixel
shown ``--scale`` x ``--scale``. Writes examples/halftones.png by default (the picture in the README).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from heoslice.grading.diffusion import DiffusionCarry
from heoslice.grading.halftone import METHODS, halftone
from heoslice.material import DEFAULT_MATERIALS

LAYER = 5
LABEL_PX = 18


def graded_strip(width: int, height: int) -> np.ndarray:
    """(height, width, 2) float: M2's share rising linearly from 0 at the left to 1 at the right."""
    share = (np.arange(width) + 0.5) / width
    mix = np.empty((height, width, 2))
    mix[..., 1] = share
    mix[..., 0] = 1.0 - share
    return mix


def method_strip(mix: np.ndarray, method: str) -> np.ndarray:
    """(height, width, 3) uint8: the layer's droplets of ``method`` in the materials' colours."""
    carry = DiffusionCarry()
    for layer in range(LAYER):
        halftone(mix, layer, method, carry=carry)
    masks = halftone(mix, LAYER, method, carry=carry)
    colours = np.array([DEFAULT_MATERIALS["M1"].color, DEFAULT_MATERIALS["M2"].color], dtype=np.uint8)
    return colours[np.argmax(masks, axis=0)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", type=Path, default=Path(__file__).with_name("halftones.png"))
    parser.add_argument("--width", type=int, default=480, help="strip width, pixels of the layer (600 dpi)")
    parser.add_argument("--height", type=int, default=120, help="strip height, pixels of the layer")
    parser.add_argument("--scale", type=int, default=2, help="screen pixels per layer pixel")
    args = parser.parse_args()
    mix = graded_strip(args.width, args.height)
    panels = []
    for method in METHODS:
        strip = method_strip(mix, method).repeat(args.scale, axis=0).repeat(args.scale, axis=1)
        label = Image.new("RGB", (strip.shape[1], LABEL_PX), "white")
        ImageDraw.Draw(label).text((4, 3), f"--halftone {method}", fill="black")
        panels += [np.asarray(label), strip]
    Image.fromarray(np.concatenate(panels)).save(args.out)
    print(args.out)


if __name__ == "__main__":
    main()
