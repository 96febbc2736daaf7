"""The shared 41-label TotalSegmentator map (../shared/data/imaging; skipped when absent): every label prints,
the one-voxel label 13 included, and each label of at least 1,000 voxels prints within 3 % of its voxel volume.

Each label gets its own material code here, so that the layers count every label's pixels; at 150 dpi and 0.5 mm
layers (the accuracy tests show the volume metric does not depend on the resolution)."""

from __future__ import annotations

import numpy as np
import pytest

from heoslice.layers.rasterising import grid_for
from heoslice.volume import load_volume
from heoslice.volume.info import label_counts
from heoslice.volume.placement import place
from heoslice.volume.resample import label_print, layer_masks

pytestmark = pytest.mark.shared_data


@pytest.fixture(scope="module")
def printed_volumes(shared_data):
    """(labels, voxel counts, printed mm^3 per label, voxel volume mm^3) of the shared map."""
    volume = load_volume(shared_data / "imaging" / "example_seg.nii.gz")
    counts = label_counts(volume)
    plan = label_print(volume, place(volume), [(label, number + 1) for number, label in enumerate(volume.labels)])
    bounds = plan.bounds_mm()
    grid = grid_for(bounds[:, :2], (150.0, 150.0), 1.0)
    layer = 0.5
    pixels = np.zeros(len(volume.labels) + 1, dtype=np.int64)
    for z in np.arange(bounds[0, 2] + layer / 2, bounds[1, 2], layer):
        _, layer_counts = layer_masks(plan, float(z), grid, len(volume.labels))
        pixels += layer_counts
    return volume.labels, counts, pixels[1:] * grid.px * grid.py * layer, volume.voxel_volume_mm3


def test_every_label_has_pixels(printed_volumes):
    labels, _, printed, _ = printed_volumes
    assert len(labels) == 41
    missing = [label.value for label, mm3 in zip(labels, printed) if mm3 <= 0]
    assert missing == []
    assert printed[[label.value for label in labels].index(13)] > 0  # the one-voxel label


def test_large_labels_keep_their_voxel_volume(printed_volumes):
    """Labels of >= 1,000 voxels: printed volume within 3 % of voxels x 27 mm^3."""
    labels, counts, printed, voxel = printed_volumes
    relative = {label.value: float(mm3 / (count * voxel) - 1) for label, count, mm3 in zip(labels, counts, printed)
                if count >= 1000}
    off = {value: round(difference, 4) for value, difference in relative.items() if abs(difference) > 0.03}
    assert off == {}
