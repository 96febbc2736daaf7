"""`heoslice preview` on hostile stacks, through the command line: decoded at the drawn size (time and memory
bounded from the child's resource usage), every option range-checked, special files refused."""

from __future__ import annotations

import hashlib
import io
import json
import os
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
import tifffile
from PIL import Image

from heoslice.preview.layer import BoxReducer
from heoslice.stack import encode_bilevel_tiff

DPI = 600.0


def measured(*args, timeout: float = 60.0) -> tuple[int, str, str, float, float]:
    """Run ``python -m heoslice ARGS`` from a wrapper process; return (exit code, stdout, stderr, wall seconds,
    peak RSS in MB), the RSS from the wrapper's RUSAGE_CHILDREN, so it is this child's own."""
    code = ("import resource, subprocess, sys, time; t = time.monotonic(); "
            "r = subprocess.run(sys.argv[1:], capture_output=True, text=True); "
            "print(r.returncode, time.monotonic() - t, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss); "
            "sys.stdout.write(r.stdout); sys.stderr.write(r.stderr)")
    done = subprocess.run([sys.executable, "-c", code, sys.executable, "-m", "heoslice", *map(str, args)],
                          capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL)
    head, _, out = done.stdout.partition("\n")
    returncode, seconds, rss_kb = head.split()
    return int(returncode), out, done.stderr, float(seconds), int(rss_kb) / 1024


def fake_stack(directory: Path, width: int, height: int, mode: str = "1", layers: int = 1) -> Path:
    """A stack of blank layers laid out as heoslice writes them (deflate strips), made without ever holding
    a layer's pixels in memory: the strips are compressed from one repeated row."""
    directory.mkdir()
    entries = []
    for index in range(layers):
        name = f"layer_{index:05d}.tif"
        if mode == "1":
            rows = np.broadcast_to(np.zeros((1, -(-width // 8)), np.uint8), (height, -(-width // 8)))
            data = encode_bilevel_tiff(rows, width, (DPI, DPI), "deflate")
        else:
            buffer = io.BytesIO()
            strip = zlib.compress(bytes(64 * width * 4), 1)
            strips = (strip if row + 64 <= height else zlib.compress(bytes((height - row) * width * 4), 1)
                      for row in range(0, height, 64))
            tifffile.imwrite(buffer, data=strips, shape=(height, width, 4), dtype=np.uint8, photometric="rgb",
                             extrasamples=["unassalpha"], compression="adobe_deflate", rowsperstrip=64,
                             resolution=(DPI, DPI), resolutionunit="INCH")
            data = buffer.getvalue()
        (directory / name).write_bytes(data)
        entries.append({"index": index, "z_mm": 0.05 + 0.1 * index, "file": name,
                        "sha256": hashlib.sha256(data).hexdigest(), "solid_pixels": 0, "open_contours": False})
    manifest = {"format": "heoslice-stack", "version": 1, "complete": True, "created_by": "test",
                "source": {"file": "x.ply", "sha256": "0" * 64}, "layer_height_mm": 0.1, "dpi": [DPI, DPI],
                "pixel_size_mm": [25.4 / DPI, 25.4 / DPI],
                "image": {"width": width, "height": height, "origin_mm": [0.0, 0.0], "mode": mode,
                          "compression": "deflate"},
                "mask": "nonzero" if mode == "1" else "alpha", "z_range_mm": [0.0, 0.1 * layers], "layers": entries}
    (directory / "manifest.json").write_text(json.dumps(manifest))
    return directory


def one_error(stderr: str) -> str:
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("heoslice: error:"), stderr
    assert "Traceback" not in stderr and "np." not in stderr
    return lines[0]


def test_box_reducer_means_match_a_reference():
    """Reducing strips of any height by a factor gives each block's mean, partial edge blocks included."""
    rng = np.random.default_rng(5)
    image = rng.integers(0, 256, (37, 23)).astype(np.uint8)
    reducer = BoxReducer(23, 37, 4, lambda m: np.repeat(np.rint(m), 3, axis=-1).astype(np.uint8))
    for start in range(0, 37, 5):
        reducer.feed([image[start:start + 5]])
    got = reducer.finish()[..., 0]
    want = np.array([[image[r:r + 4, c:c + 4].mean() for c in range(0, 23, 4)] for r in range(0, 37, 4)])
    assert np.array_equal(got, np.rint(want).astype(np.uint8))


def test_huge_bilevel_layer_previews_in_bounded_memory(tmp_path):
    """A ~100 KB deflate layer declaring 16384^2 1-bit pixels previews (reduced to 4096 px) in < 20 s and
    < 400 MB: decoded strip by strip and decimated while decoding (the whole layer would need > 1 GB)."""
    stack = fake_stack(tmp_path / "huge", 16384, 16384)
    assert (stack / "layer_00000.tif").stat().st_size < 1 << 20
    code, out, err, seconds, rss = measured("preview", stack, "--layer", "0", "-o", tmp_path / "p.png")
    assert code == 0, err
    width, height = Image.open(tmp_path / "p.png").size
    assert width == 4096 and 4096 < height < 4096 + 100  # the layer, and the annotation footer below it
    assert seconds < 20 and rss < 400, (seconds, rss)


def test_huge_rgba_layer_previews_in_bounded_memory(tmp_path):
    """An RGBA layer of 8192^2 pixels previews at --size 512 in < 400 MB (the decoded layer alone is 256 MB,
    its float composite over a GB)."""
    stack = fake_stack(tmp_path / "rgba", 8192, 8192, mode="RGBA")
    code, out, err, seconds, rss = measured("preview", stack, "--layer", "0", "--size", "512",
                                            "-o", tmp_path / "p.png")
    assert code == 0, err
    width, height = Image.open(tmp_path / "p.png").size
    assert width == 512 and 512 < height < 512 + 100  # the layer, and the annotation footer below it
    assert seconds < 20 and rss < 400, (seconds, rss)


@pytest.mark.parametrize("options, flag", [
    (["--sheet", "--layers", ",".join(["0"] * 20000)], "--layers"),
    (["--sheet", "--tile", "1000000"], "--tile"),
    (["--sheet", "--columns", "1000000000"], "--columns"),
    (["--size", "100000"], "--size"),
    (["--size", "1e6"], "--size"),
    (["--layer", "99"], "--layer"),
])
def test_preview_options_are_range_checked(tmp_path, options, flag):
    """Absurd sheet entries, tile, column and size values: one line naming the option, exit 2, quickly."""
    stack = fake_stack(tmp_path / "small", 64, 64, layers=3)
    code, out, err, seconds, rss = measured("preview", stack, *options, "-o", tmp_path / "p.png")
    assert code == 2 and flag in one_error(err), err
    assert seconds < 10 and rss < 300, (seconds, rss)
    assert not (tmp_path / "p.png").exists()


def test_sheet_larger_than_the_limit_is_refused_before_drawing(tmp_path):
    """400 layers at 1024 px tiles would be a 21k x 21k px sheet: refused naming --tile, exit 2."""
    stack = fake_stack(tmp_path / "many", 32, 32, layers=400)
    code, out, err, seconds, rss = measured("preview", stack, "--sheet", "--layers", "0:400", "--tile", "1024",
                                            "-o", tmp_path / "s.png")
    assert code == 2 and "--tile" in one_error(err), err
    assert seconds < 10


def test_fifo_layer_is_refused_not_waited_on(tmp_path):
    """A layer file replaced by a FIFO: preview (like verify) refuses it with one line instead of blocking."""
    stack = fake_stack(tmp_path / "fifo", 64, 64, layers=2)
    (stack / "layer_00001.tif").unlink()
    os.mkfifo(stack / "layer_00001.tif")
    code, out, err, seconds, rss = measured("preview", stack, "--layer", "1", "-o", tmp_path / "p.png", timeout=30)
    assert code == 4 and "not a regular file" in one_error(err), err
    code, out, err, seconds, rss = measured("preview", stack, "--sheet", "-o", tmp_path / "s.png", timeout=30)
    assert code == 4 and "not a regular file" in one_error(err), err


def test_a_layer_of_oblong_pixels_draws_at_its_true_aspect(tmp_path, run_cli):
    """A stack sliced at 150 x 75 dpi (pixels twice as tall as wide): a layer of a 20 x 20 mm box draws square (its
    drawn width and height within 2 px of each other), not squashed 2:1 (a contact sheet's tiles are these images)."""
    from heoslice import procedural
    from heoslice.preview.layer import layer_image
    from heoslice.stack import read_manifest

    procedural.box((20.0, 20.0, 2.0)).export(tmp_path / "box.ply")
    code, _, err = run_cli("slice", tmp_path / "box.ply", "--layer", "1", "--dpi", "150x75", "--margin", "2",
                           "-o", tmp_path / "stack")
    assert code == 0, err
    manifest = read_manifest(tmp_path / "stack")
    image = np.asarray(layer_image(tmp_path / "stack", 1, manifest=manifest))
    solid = np.argwhere((image != image[0, 0]).any(axis=2))
    height, width = solid.max(axis=0) - solid.min(axis=0) + 1
    assert abs(int(width) - int(height)) <= 2, (width, height)
