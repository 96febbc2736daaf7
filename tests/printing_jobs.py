"""Synthetic print jobs for the printing tests and benchmarks (fixtures, not part of the library)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

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


def make_stack(directory: Path, masks: list[np.ndarray], droplets: list[list[np.ndarray]] | None = None) -> Path:
    """A stack as docs/stack-format.md describes it (L images 0/255, 600 dpi), with optional droplet channels
    (per layer, a list of masks partitioning its solid pixels, 1-bit as the format requires)."""
    import tifffile

    directory.mkdir()
    height, width = masks[0].shape
    layers = []

    def write(name, mask, bilevel=False):
        pixels = mask.astype(bool) if bilevel else (mask * 255).astype(np.uint8)
        tifffile.imwrite(directory / name, pixels, resolution=(600.0, 600.0), resolutionunit="INCH",
                         photometric="minisblack")
        return hashlib.sha256((directory / name).read_bytes()).hexdigest()

    for index, mask in enumerate(masks):
        entry = {"index": index, "z_mm": 0.05 + 0.1 * index, "file": f"layer_{index:05d}.tif",
                 "sha256": write(f"layer_{index:05d}.tif", mask), "solid_pixels": int(mask.sum()),
                 "open_contours": False}
        if droplets is not None:
            entry["channels"] = []
            for number, drop in enumerate(droplets[index]):
                name = f"layer_{index:05d}_drop{number}.tif"
                entry["channels"].append({"file": name, "sha256": write(name, drop, bilevel=True)})
        layers.append(entry)
    manifest = {"format": "heoslice-stack", "version": 1, "complete": True, "created_by": "test",
                "source": {"file": "x.ply", "sha256": "0" * 64}, "layer_height_mm": 0.1, "dpi": [600.0, 600.0],
                "pixel_size_mm": [25.4 / 600, 25.4 / 600],
                "image": {"width": width, "height": height, "origin_mm": [0.0, 0.0], "mode": "L",
                          "compression": "raw"},
                "mask": "nonzero", "z_range_mm": [0.0, 0.1 * len(masks)], "layers": layers}
    (directory / "manifest.json").write_text(json.dumps(manifest))
    return directory


def disc_masks(count: int, width: int = 40, height: int = 30) -> list[np.ndarray]:
    yy, xx = np.mgrid[0:height, 0:width]
    return [(xx - width / 2) ** 2 + (yy - height / 2) ** 2 < (3 + k) ** 2 for k in range(count)]
