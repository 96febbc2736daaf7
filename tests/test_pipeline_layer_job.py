"""Tests of pipeline/layer_job.py: what one layer leaves to the next."""

from __future__ import annotations

import numpy as np
import tifffile


def test_a_layer_takes_the_last_layers_tiff_only_for_the_same_solid_bits():
    """A 1-bit layer takes the last layer's encoded TIFF (the same bytes object) only when its solid bits are
    those bits: as many solid pixels elsewhere get a TIFF of their own, which decodes to them."""
    import io
    from types import SimpleNamespace

    from heoslice.pipeline.layer_job import PipelineCache, _solid_tiff

    job = SimpleNamespace(grid=SimpleNamespace(width=40), dpi=(600.0, 600.0), compression="deflate",
                          layer_height_mm=0.1)
    mask = np.zeros((30, 40), dtype=bool)
    mask[5:15, 8:20] = True
    moved = np.roll(mask, 7, axis=1)
    cache = PipelineCache()
    first = _solid_tiff(np.packbits(mask, axis=1), int(mask.sum()), job, cache, 1)
    assert _solid_tiff(np.packbits(mask, axis=1), int(mask.sum()), job, cache, 1) is first
    other = _solid_tiff(np.packbits(moved, axis=1), int(moved.sum()), job, cache, 1)
    assert np.array_equal(tifffile.imread(io.BytesIO(other)).astype(bool), moved)
    assert np.array_equal(tifffile.imread(io.BytesIO(first)).astype(bool), mask)


def test_multi_material_layers_are_deflated_harder_than_one_material_ones(tmp_path):
    """Every 1-bit solid layer of a droplet-mask stack holds its pixels deflated by zlib-ng at deflate_level(True),
    and its masks as mask_deflation says (every method's by zlib-ng at level 2, none by ISA-L, whose bytes are not
    reproducible); a one-material stack's layers at
    deflate_level(False), level 1 (its fastest). Each file is the bytes encode_bilevel_tiff writes so, and not
    another way."""
    from helpers import in_process

    from heoslice import procedural
    from heoslice.grading.halftone import METHODS
    from heoslice.stack import encode_bilevel_tiff
    from heoslice.stack.tiff import MASK_DEFLATION, Deflation, deflate_level, mask_deflation

    procedural.sphere(6.0, subdivisions=3).export(tmp_path / "ball.ply")
    assert deflate_level(False) == 1 < deflate_level(True)
    assert set(MASK_DEFLATION) == {None, *METHODS}
    assert {mask_deflation(method) for method in MASK_DEFLATION} == {Deflation("zlib-ng", deflate_level(True))}
    graded = ("--grade", "linear", "--to", "0,255,0", "--channels", "--halftone")
    plain = Deflation("zlib-ng", deflate_level(False))
    cases = [("plain", (), plain, plain)]
    cases += [(method, (*graded, method), Deflation("zlib-ng", deflate_level(True)), mask_deflation(method))
              for method in METHODS]
    ways = {Deflation("zlib-ng", 1), Deflation("zlib-ng", 2), Deflation("isa-l", 2)}
    for name, extra, solid_way, mask_way in cases:
        assert in_process("slice", tmp_path / "ball.ply", "--layer", "2", "--dpi", "300", "-o", tmp_path / name,
                          *extra) == 0
        files = sorted((tmp_path / name).glob("layer_*.tif"))
        assert len(files) == (6 if name == "plain" else 18)
        for path in files:
            with tifffile.TiffFile(path) as tiff:
                page = tiff.pages.first
                pixels, spacing = page.asarray(), tiff.imagej_metadata["spacing"]
            way = mask_way if "_M" in path.name else solid_way
            encoded = {other: encode_bilevel_tiff(np.packbits(pixels, axis=1), pixels.shape[1], (300.0, 300.0),
                                                  "deflate", spacing, level=other.level, encoder=other.encoder)
                       for other in ways}
            assert path.read_bytes() == encoded[way], path.name
            if pixels.any():
                assert len(set(encoded.values())) == len(ways), path.name
