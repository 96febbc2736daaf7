"""Tests of heoslice.volume.resample's label rule on label maps: a thin label (a one-voxel vessel or wall, a
2 x 2 vessel) inside an organ prints its voxel volume, measured from the stack's TIFFs, and so does the organ
around it; nothing steps between a 63- and a 64-voxel vessel; random small label blocks print each label near
its voxel volume; map_boost fades with thickness and puts a higher priority first."""

from __future__ import annotations

import tempfile
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from volume_phantoms import grid_affine, write_nifti

from heoslice.material import Material, PartSetting
from heoslice.pipeline import SliceSpec
from heoslice.pipeline.volume_job import plan_labels, slice_volume_to_stack
from heoslice.stack import read_layer_channels
from heoslice.volume import load_volume
from heoslice.volume.resample import BOOST, THIN_RADIUS, map_boost

#: A label's printed volume may be this far (fraction) from its voxel volume at 1 mm voxels, 0.5 mm layers.
BOUND = 0.1


def printed_volumes(tmp_path, data: np.ndarray, name: str = "stack", dpi: float = 200.0,
                    priorities: dict[int, int] | None = None) -> dict[int, float]:
    """Slice a label map of 1 mm voxels (each label its own material) and return each label's printed volume
    over its voxel volume, counted from its droplet-mask TIFFs."""
    volume = load_volume(write_nifti(tmp_path / f"{name}.nii.gz", data, grid_affine(1.0, [0, 0, 0])))
    values = [int(v) for v in np.unique(data) if v > 0]
    table = {f"m{v}": Material(f"m{v}", (10 * v, 0, 0), channel=None) for v in values}
    plan = plan_labels(volume, table, {str(v): PartSetting(f"m{v}", (priorities or {}).get(v)) for v in values})
    spec = SliceSpec(layer_height_mm=0.5, dpi=(dpi, dpi), jobs=1)
    manifest, _ = slice_volume_to_stack(volume, tmp_path / name, spec, plan)
    names = [channel["material"] for channel in manifest["layers"][0]["channels"]]
    pixels = np.zeros(len(names))
    for entry in manifest["layers"]:
        pixels += read_layer_channels(tmp_path / name, manifest, entry["index"]).sum(axis=(1, 2))
    px, py = manifest["pixel_size_mm"]
    printed = dict(zip(names, pixels * px * py * manifest["layer_height_mm"]))
    return {v: printed[f"m{v}"] / np.count_nonzero(data == v) for v in values}


def vessel_block() -> np.ndarray:
    """An organ (label 1, 14 x 14 x 20 voxels) holding a one-voxel vessel (2) and a 2 x 2 vessel (3) along z
    and a one-voxel wall (4) across it; a free one-voxel line (5) beside it."""
    data = np.zeros((18, 24, 20), np.uint8)
    data[2:16, 2:16, :] = 1
    data[5, 5, :] = 2
    data[10:12, 5:7, :] = 3
    data[2:16, 11, :] = 4
    data[16, 20, :] = 5
    return data


def test_thin_labels_inside_an_organ_print_their_voxel_volume(tmp_path):
    """The one-voxel vessel, the 2 x 2 vessel and the one-voxel wall inside the organ, and the free line, each
    print within BOUND of their voxel volume (the organ's field reaching into them took 30-70 % before); the
    organ, whose level is set again outside what they take back, within BOUND / 2 (9 % short without)."""
    ratios = printed_volumes(tmp_path, vessel_block())
    for label, ratio in ratios.items():
        assert abs(ratio - 1.0) < BOUND, (label, ratios)
    assert abs(ratios[1] - 1.0) < BOUND / 2, ratios


def test_no_step_between_a_63_and_a_64_voxel_vessel(tmp_path):
    """Two one-voxel vessels of 63 and 64 voxels in one organ print the same fraction of their voxel volume
    (within 2 %): the rule follows thickness, not voxel count."""
    data = np.zeros((14, 14, 72), np.uint8)
    data[2:12, 2:12, :] = 1
    data[4, 4, 4:67] = 2
    data[9, 9, 4:68] = 3
    ratios = printed_volumes(tmp_path, data, dpi=150.0)
    assert abs(ratios[2] - ratios[3]) < 0.02, ratios
    assert abs(ratios[2] - 1.0) < BOUND and abs(ratios[3] - 1.0) < BOUND, ratios


def test_priority_decides_where_two_label_fields_overlap(tmp_path):
    """Given a higher priority, the organ takes the one-voxel vessel's pixels its field covers (the vessel's
    voxel but near its centre): the vessel prints a fifth less, the organ more; without it, the thin vessel
    keeps its volume."""
    data = np.zeros((12, 12, 24), np.uint8)
    data[2:10, 2:10, :] = 1
    data[6, 6, :] = 2
    plain = printed_volumes(tmp_path, data, "plain")
    first = printed_volumes(tmp_path, data, "first", priorities={1: 1})
    assert abs(plain[2] - 1.0) < BOUND
    assert first[2] < plain[2] - 0.2 and first[1] > plain[1]


def _random_block(draw) -> np.ndarray:
    """An organ (label 1, 16 x 12-16 voxels, its faces a voxel inside the block) holding one to three slabs of
    labels 2-4 through its height, each 1-3 voxels thick and up to the organ's width wide, in rows of its own
    (two thin labels side by side fight as two organs do: "most inside wins"); walls of more than 64 voxels
    are common."""
    shape = (18, draw(st.integers(14, 18)), 12)
    data = np.zeros(shape, np.uint8)
    data[1:-1, 1:-1, 1:-1] = 1
    for value in range(2, draw(st.integers(2, 4)) + 1):
        thick, wide = draw(st.integers(1, 3)), draw(st.integers(1, shape[1] - 4))
        row = 5 * (value - 2) + 1 + draw(st.integers(0, 4 - thick))
        column = draw(st.integers(1, shape[1] - wide - 1))
        data[row:row + thick, column:column + wide, 1:-1] = value
    return data


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.data())
def test_random_label_blocks_print_each_label_near_its_voxel_volume(tmp_path, data):
    """Random organs holding thinner slabs: every label prints within 1.5 BOUND of its voxel volume ("most
    inside wins" left walls at 50-80 %), and the labels
    together within BOUND / 2 of the whole."""
    block = _random_block(data.draw)
    with tempfile.TemporaryDirectory(dir=tmp_path) as folder:
        ratios = printed_volumes(Path(folder), block, dpi=150.0)
    for label, ratio in ratios.items():
        assert abs(ratio - 1.0) < 1.5 * BOUND, (label, ratios)
    counts = {label: np.count_nonzero(block == label) for label in ratios}
    total = sum(ratios[label] * counts[label] for label in ratios) / sum(counts.values())
    assert abs(total - 1.0) < BOUND / 2, (total, ratios)


def test_map_boost_fades_with_thickness_and_ranks_priority_first():
    """The boost is THIN_RADIUS less the inscribed radius (0 at or above it: no step), and a label of higher
    priority is boosted above any thinner label of lower priority."""
    fields = [SimpleNamespace(radius=r) for r in (1.0, 2.0, 2.9, 3.0, 12.0)]
    assert map_boost(fields).tolist() == pytest.approx([THIN_RADIUS - 1, THIN_RADIUS - 2, THIN_RADIUS - 2.9, 0, 0],
                                                       abs=1e-6)
    ranked = map_boost(fields, [0, 0, 0, 0, 3])
    assert ranked[4] >= BOOST and ranked[:4].max() < BOOST
    assert map_boost(fields, [-2, 5, 5, 0, 0]).tolist() == pytest.approx(
        [THIN_RADIUS - 1, 2 * BOOST + 1, 2 * BOOST + 0.1, BOOST, BOOST], abs=1e-2)


@pytest.mark.parametrize("wall", [3, 4])
def test_a_cyst_stays_inside_its_wall(tmp_path, wall):
    """A ball (label 1) wrapped in a thin wall (label 2, ``wall`` voxels): each prints within BOUND of its voxel
    volume, the cyst inside the wall, not grown through it (an organ yields at most BAND voxels outwards: the
    cyst printed 132-160 % and the wall 62-69 % when its level was reset without bound)."""
    index = np.indices((34, 34, 34))
    radius = np.sqrt(((index - 16.5) ** 2).sum(axis=0))
    data = np.zeros((34, 34, 34), np.uint8)
    data[radius <= 14] = 2
    data[radius <= 14 - wall] = 1
    ratios = printed_volumes(tmp_path, data, dpi=100.0)
    assert all(abs(ratio - 1.0) < BOUND for ratio in ratios.values()), ratios


def test_a_thin_vessel_out_of_a_prioritised_organ_keeps_its_width(tmp_path):
    """A one-voxel vessel running through an organ given a higher priority (half its length) and out of it on
    both sides: the organ takes the vessel inside it, and outside the vessel prints its own cross-section, so it
    prints about half its voxel volume (a thin label does not yield: its lost volume moved outside the organ,
    about twice its width there, and the total looked right at 0.94)."""
    data = np.zeros((12, 12, 40), np.uint8)
    data[2:10, 2:10, 10:30] = 1
    data[6, 6, :] = 2
    ratios = printed_volumes(tmp_path, data, priorities={1: 1})
    assert 0.4 < ratios[2] < 0.75, ratios
