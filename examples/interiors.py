"""What the interior of a coloured model gets, in each of slice's modes: a vertical section through the same
model, side by side (issue 44; README "The design travels with the model").

Usage: python examples/interiors.py [OUT.png] [--dpi 200] [--layer 0.2] [--size 360]

The model is a ball (heoslice.procedural.sphere, radius 10 mm) coloured by `heoslice color` with a sine of
3 periods of the distance to its bottom pole (--ref point --at 0,0,-10), from M1 (light grey) to M2 (green). It is sliced as
RGBA preview stacks (the materials' colours mixed per voxel, not halftoned) in four ways, and each stack is
cut at x = 0 (heoslice.preview.section_image):

  field               the default: every voxel gets f(r) of its own 3-D distance: shells about the pole inside
  contour             --interior contour: each layer's contour material carried inward (the paper's
                      layer-wise distribution): every contour point of a layer is equally far from the pole,
                      so each layer is one material: flat bands along z
  graded (layer)      --grade linear --depth 4: eq. 8-10 sub-regions offset inward per layer (the paper's);
                      the top and bottom skins are thin
  graded (surface)    the same with --depth-from surface: the depth measured in 3D, every skin alike

Writes OUT.png (default examples/interiors.png, the picture in the README) and prints what each panel shows.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

from PIL import Image, ImageDraw

from heoslice import procedural
from heoslice.preview import section_image

PANELS = (
    ("field", ["--interior", "field"]),
    ("contour", ["--interior", "contour"]),
    ("graded (layer)", ["--grade", "linear", "--depth", "4"]),
    ("graded (surface)", ["--grade", "linear", "--depth", "4", "--depth-from", "surface"]),
)


def heoslice(*args) -> None:
    """Run the heoslice command (the same Python), stopping the script with its error line if it fails."""
    done = subprocess.run([sys.executable, "-m", "heoslice", *map(str, args)], capture_output=True, text=True)
    if done.returncode:
        sys.exit(done.stderr.strip() or f"heoslice {args[0]} failed ({done.returncode})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("out", nargs="?", type=Path, default=Path(__file__).with_name("interiors.png"))
    parser.add_argument("--dpi", type=float, default=200.0)
    parser.add_argument("--layer", type=float, default=0.2)
    parser.add_argument("--size", type=int, default=360)
    options = parser.parse_args()
    with tempfile.TemporaryDirectory() as work:
        work = Path(work)
        procedural.sphere(radius=10.0, subdivisions=4).export(work / "ball.ply")
        heoslice("color", work / "ball.ply", "--ref", "point", "--at", "0,0,-10", "--func", "sine", "--periods", "3",
                 "-o", work / "ball_sine.ply")
        panels = []
        for title, extra in PANELS:
            stack = work / title.replace(" ", "_").replace("(", "").replace(")", "")
            model = work / ("ball.ply" if extra[0] == "--grade" else "ball_sine.ply")
            heoslice("slice", model, "--layer", options.layer, "--dpi", options.dpi, "--rgba", "-o", stack, *extra)
            panels.append((title, section_image(stack, "x", 0.0, options.size)))
            print(f"{title}: {' '.join(extra)}")
    width = sum(image.width for _, image in panels) + 10 * (len(panels) + 1)
    height = max(image.height for _, image in panels) + 40
    sheet = Image.new("RGB", (width, height), "white")
    draw = ImageDraw.Draw(sheet)
    left = 10
    for title, image in panels:
        sheet.paste(image, (left, 30))
        draw.text((left, 8), title, fill="black")
        left += image.width + 10
    sheet.save(options.out)
    print(f"wrote {options.out}")


if __name__ == "__main__":
    main()
