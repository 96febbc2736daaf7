"""Synthetic print jobs for the printing tests and benchmarks (fixtures, not part of the library)."""

from __future__ import annotations

import numpy as np

from heoslice.printing import JobSpec, LayerSource, pack_mask


def synthetic_job(layer_count: int, width: int = 64, height: int = 16, channels: int = 1,
                  seed: int = 0, job_id: int = 0x5EED) -> tuple[JobSpec, LayerSource]:
    """A job of random blob masks (compressible, distinct per layer)."""
    job = JobSpec(job_id, layer_count, channels, width, height)

    def get_layer(index: int) -> list[bytes]:
        rng = np.random.default_rng([seed, index])
        out = []
        for _ in range(channels):
            yy, xx = np.mgrid[0:height, 0:width]
            cx, cy, r = rng.uniform(0, width), rng.uniform(0, height), rng.uniform(2, max(width, height) / 2)
            out.append(pack_mask((xx - cx) ** 2 + (yy - cy) ** 2 < r * r))
        return out

    return job, get_layer


def random_job(layer_count: int, rows: int, seed: int = 0, job_id: int = 0xBEEF) -> tuple[JobSpec, LayerSource]:
    """A one-channel job of incompressible random layers, 2048 px wide and ``rows`` high (256 bytes a row)."""
    job = JobSpec(job_id, layer_count, 1, 2048, rows)
    layer_bytes = job.channel_bytes

    def get_layer(index: int) -> list[bytes]:
        return [np.random.default_rng([seed, index]).integers(0, 256, layer_bytes, dtype=np.uint8).tobytes()]

    return job, get_layer
