"""Layer TIFFs as Fiji, napari and tifffile read them: calibrated in mm with the layer height as Z spacing,
and solid shown dark on white in the files as in the previews."""

from __future__ import annotations

import io
import subprocess
import sys

import numpy as np
import pytest
import tifffile
from helpers import in_process
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

import heoslice
import heoslice.stack.tiff
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


def _tifffile_reference(packed: np.ndarray, width: int, dpi, compression: str, spacing, rows: int, level: int) -> bytes:
    """The file tifffile itself writes from the same compressed strips and tags (the test's reference)."""
    from heoslice.stack.tiff import COMPRESSIONS, _strip_codec, calibration

    codec = _strip_codec(compression, level)
    strips = [codec(packed[row:row + rows].tobytes()) for row in range(0, packed.shape[0], rows)]
    buffer = io.BytesIO()
    tifffile.imwrite(buffer, data=iter(strips), shape=(packed.shape[0], width), dtype=bool,
                     compression=COMPRESSIONS[compression], photometric="miniswhite", rowsperstrip=rows,
                     software=f"heoslice {heoslice.__version__}", **calibration(dpi, spacing))
    return buffer.getvalue()


@settings(max_examples=60, deadline=None)
@given(height=st.integers(1, 700), width=st.integers(1, 90), rows=st.sampled_from([1, 7, 64, 256]),
       compression=st.sampled_from(["deflate", "lzw", "packbits"]), level=st.integers(1, 3),
       dpi=st.sampled_from([(600.0, 600.0), (200.0, 100.0), (1234.5, 77.0)]),
       spacing=st.sampled_from([None, 0.1, 0.025]), density=st.floats(0, 1), seed=st.integers(0, 2**16))
def test_bilevel_layers_are_the_bytes_tifffile_writes(height, width, rows, compression, level, dpi, spacing,
                                                       density, seed):
    """A 1-bit layer laid out from the recalled layout of its form is byte for byte the file tifffile writes
    from the same strips, for any size, strip height, codec, resolution and spacing (one strip, many)."""
    from heoslice.stack.tiff import encode_bilevel_tiff

    rng = np.random.default_rng(seed)
    bits = rng.random((height, width)) < density
    packed = np.packbits(bits, axis=1)
    data = encode_bilevel_tiff(packed, width, dpi, compression, spacing, rows_per_strip=rows, level=level)
    assert data == _tifffile_reference(packed, width, dpi, compression, spacing, rows, level)
    assert np.array_equal(tifffile.imread(io.BytesIO(data)), bits)


@settings(max_examples=60, deadline=None)
@given(height=st.integers(1, 900), width=st.integers(1, 60), rows=st.sampled_from([7, 64, 256]),
       compression=st.sampled_from(["deflate", "lzw", "packbits"]), level=st.integers(1, 3),
       band=st.tuples(st.integers(0, 900), st.integers(0, 900)), seed=st.integers(0, 2**16))
def test_strips_off_the_part_rows_are_the_blank_strips_tifffile_writes(height, width, rows, compression, level,
                                                                       band, seed):
    """Told the rows that may hold set bits (``rows``: every set bit lies within them), a layer is byte for
    byte the file tifffile writes from all its strips compressed: the strips wholly outside, taken as blank
    (one compressed blank strip per size), are the strips of zeros they are."""
    from heoslice.stack.tiff import encode_bilevel_tiff

    first, stop = sorted(min(value, height) for value in band)
    bits = np.zeros((height, width), dtype=bool)
    bits[first:stop] = np.random.default_rng(seed).random((stop - first, width)) < 0.4
    packed = np.packbits(bits, axis=1)
    data = encode_bilevel_tiff(packed, width, (600.0, 600.0), compression, 0.1, rows_per_strip=rows, level=level,
                               rows=(first, stop))
    assert data == _tifffile_reference(packed, width, (600.0, 600.0), compression, 0.1, rows, level)
    assert np.array_equal(tifffile.imread(io.BytesIO(data)), bits)


def test_a_typical_layer_is_laid_out_from_its_recalled_layout():
    """The fast path is taken: tifffile's layout of a 600 dpi deflate layer is recalled (not None), so a
    tifffile that lays files out otherwise shows here, not only as a slower slice."""
    from heoslice.stack.tiff import BilevelForm, bilevel_layout

    assert bilevel_layout(BilevelForm(2952, 3827, (600.0, 600.0), "deflate", 0.1, 256)) is not None


def test_a_layout_tifffile_no_longer_writes_falls_back_to_tifffile(monkeypatch):
    """When the recalled layout is unusable (a tifffile that lays files out otherwise), the layer is still
    tifffile's own file."""
    from heoslice.stack import tiff

    monkeypatch.setattr(tiff, "bilevel_layout", lambda form: None)
    packed = np.packbits(np.eye(300, 40, dtype=bool), axis=1)
    data = tiff.encode_bilevel_tiff(packed, 40, (600.0, 600.0), "deflate", 0.1)
    assert data == _tifffile_reference(packed, 40, (600.0, 600.0), "deflate", 0.1, 256, 1)


def _documented_pillow_reading(document: str) -> str:
    """The one line a document gives for reading a mask with Pillow (the code before its comment)."""
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / document).read_text(encoding="utf-8")
    lines = [line.split("`")[1] if "`solid = " in line else line.strip().split("#")[0].strip()
             for line in text.splitlines() if "solid = " in line and "PIL.Image.open(path)" in line]
    assert lines, f"{document} gives no one-line Pillow reading of a mask"
    return lines[0]


@pytest.mark.parametrize("document", ["README.md", "docs/stack-format.md"])
def test_the_documented_pillow_one_liner_reads_solid_as_true(tmp_path, document):
    """The line the README and the stack format give for reading a 1-bit layer with Pillow gives True exactly
    where the layer is solid (as tifffile reads it), on a layer whose solid part is not symmetric."""
    import PIL.Image

    solid = np.zeros((37, 53), bool)
    solid[5:20, 3:30] = True
    solid[25, 40:] = True
    path = tmp_path / "layer_00000.tif"
    path.write_bytes(heoslice.stack.tiff.encode_tiff(solid, (600.0, 600.0), "deflate", 0.1))
    assert np.array_equal(tifffile.imread(path), solid)
    namespace = {"numpy": np, "PIL": PIL, "path": path}
    exec(_documented_pillow_reading(document), namespace)  # noqa: S102 - the documented line itself
    assert namespace["solid"].dtype == bool and np.array_equal(namespace["solid"], solid)
