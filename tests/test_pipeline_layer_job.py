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
    first = _solid_tiff(np.packbits(mask, axis=1), int(mask.sum()), job, cache)
    assert _solid_tiff(np.packbits(mask, axis=1), int(mask.sum()), job, cache) is first
    other = _solid_tiff(np.packbits(moved, axis=1), int(moved.sum()), job, cache)
    assert np.array_equal(tifffile.imread(io.BytesIO(other)).astype(bool), moved)
    assert np.array_equal(tifffile.imread(io.BytesIO(first)).astype(bool), mask)
