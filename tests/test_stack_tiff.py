"""Layer TIFFs as Fiji, napari and tifffile read them: calibrated in mm with the layer height as Z spacing,
and solid shown dark on white in the files as in the previews."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import tifffile
from helpers import in_process
from PIL import Image

from heoslice import procedural


def test_layers_are_calibrated_in_mm_with_the_layer_height_as_z_spacing(tmp_path):
    """Every layer and droplet mask carries ImageJ metadata unit=mm, spacing=layer height, and a resolution
    in pixels per mm that matches the manifest's dpi; 1-bit files are min-is-white, so Pillow (like Fiji)
    shows solid pixels dark, the same way `preview` draws them."""
    procedural.sphere(4.0, subdivisions=3).export(tmp_path / "ball.ply")
    assert in_process("slice", tmp_path / "ball.ply", "--layer", "1", "--dpi", "200x100", "--grade", "linear",
                      "--to", "0,255,0", "--channels", "-o", tmp_path / "s") == 0
    files = sorted((tmp_path / "s").glob("layer_00004*.tif"))
    assert len(files) == 3
    for path in files:
        with tifffile.TiffFile(path) as tiff:
            assert tiff.imagej_metadata["unit"] == "mm" and tiff.imagej_metadata["spacing"] == 1.0
            page = tiff.pages.first
            x_res, y_res = page.tags["XResolution"].value, page.tags["YResolution"].value
            assert np.allclose([x_res[0] / x_res[1], y_res[0] / y_res[1]], [200 / 25.4, 100 / 25.4])
            assert page.photometric == tifffile.PHOTOMETRIC.MINISWHITE
            stored = page.asarray()
        shown = np.asarray(Image.open(path).convert("L"))
        assert stored.any() and np.array_equal(shown[stored], np.zeros(int(stored.sum()), np.uint8))
        assert (shown[~stored] == 255).all()
    preview = tmp_path / "p.png"
    done = subprocess.run([sys.executable, "-m", "heoslice", "preview", tmp_path / "s", "--layer", "4",
                           "-o", preview], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
