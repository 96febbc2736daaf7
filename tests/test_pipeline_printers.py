"""Tests of heoslice.pipeline.printers and ``slice --printer``: the presets' grid, pitch, padding and material
limit reach the stack; a preset and an option that disagree are one line; halftoning happens on the printer's
own (anisotropic) grid, not on a square one stretched afterwards."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from helpers import heoslice, in_process

from heoslice import procedural
from heoslice.errors import InputError
from heoslice.export.voxel_print import sample_indices
from heoslice.grading import GradeSpec, RegionSpec
from heoslice.material import DEFAULT_MATERIALS, Material, make_function
from heoslice.mesh import load_mesh
from heoslice.pipeline import SliceSpec, slice_to_stack
from heoslice.pipeline.printers import PRESETS, printer_preset
from heoslice.stack import read_layer_channels, read_layer_mask

GREEN = Material("green", (0, 255, 0))


def _grade(**changes) -> GradeSpec:
    fields = dict(regions=RegionSpec(nozzle_mm=0.3), function=make_function("linear"), target=GREEN, start=None,
                  base=DEFAULT_MATERIALS["M1"], second=DEFAULT_MATERIALS["M2"])
    return GradeSpec(**{**fields, **changes})


@pytest.fixture(scope="module")
def slab(tmp_path_factory):
    """A 6 x 4 mm slab, 0.05 mm thick (two J750 layers), as a PLY."""
    path = tmp_path_factory.mktemp("printers") / "slab.ply"
    procedural.box((6.0, 4.0, 0.05)).export(path)
    return load_mesh(path)


def test_every_preset_is_a_frozen_row_of_the_one_table():
    """The table holds the J750, J850 and Connex3 modes as frozen dataclasses: the J-series at 600 x 300 dpi and
    27 or 14 um, Connex3 at 30 um and 3 materials, every width padded to 16 px."""
    assert {"j750-27um", "j750-14um", "j850-27um", "connex-30um"} <= set(PRESETS)
    j750 = printer_preset("j750-27um")
    assert (j750.dpi, j750.layer_mm, j750.pad_x_px, j750.max_materials) == ((600.0, 300.0), 0.027, 16, 6)
    assert printer_preset("j750-14um").layer_mm == 0.014
    assert printer_preset("connex-30um").layer_mm == 0.030 and printer_preset("connex-30um").max_materials == 3
    assert all(preset.pad_x_px == 16 for preset in PRESETS.values())
    with pytest.raises(dataclasses.FrozenInstanceError):
        j750.layer_mm = 0.1
    with pytest.raises(InputError, match="j750-27um"):
        printer_preset("j760")


def test_the_j750_preset_slices_at_600_by_300_dpi_27_um_with_the_width_a_multiple_of_16(slab, tmp_path):
    """A stack sliced with the J750 preset has 600 x 300 dpi, 0.027 mm layers and a width that is a multiple of
    16 px (the part's own width is not)."""
    preset = printer_preset("j750-27um")
    manifest, _ = slice_to_stack(slab, tmp_path / "s", SliceSpec(layer_height_mm=0.027, dpi=(600.0, 300.0),
                                                                  grade=_grade(), channels=True, printer=preset))
    assert manifest["dpi"] == [600.0, 300.0] and manifest["layer_height_mm"] == 0.027
    assert manifest["image"]["width"] % 16 == 0
    plain, _ = slice_to_stack(slab, tmp_path / "p", SliceSpec(layer_height_mm=0.027, dpi=(600.0, 300.0),
                                                               grade=_grade(), channels=True))
    assert plain["image"]["width"] % 16 != 0
    assert manifest["image"]["width"] == -(-plain["image"]["width"] // 16) * 16


def test_a_spec_whose_grid_is_not_its_presets_and_too_many_materials_are_refused(slab, tmp_path):
    """A SliceSpec with a preset but another resolution or pitch is refused; so is a slice of more materials than
    the printer jets (Connex3: 3)."""
    with pytest.raises(InputError, match="printer: j750-27um"):
        SliceSpec(layer_height_mm=0.1, dpi=(600.0, 300.0), printer=printer_preset("j750-27um"))
    connex = printer_preset("connex-30um")
    four = _grade(start=Material("red", (255, 0, 0)))
    assert len(four.channel_materials()) == 4
    with pytest.raises(InputError, match="at most 3"):
        slice_to_stack(slab, tmp_path / "c", SliceSpec(layer_height_mm=0.030, dpi=(600.0, 300.0), grade=four,
                                                      channels=True, printer=connex))
    assert not (tmp_path / "c" / "manifest.json").exists()


@pytest.mark.parametrize("method", ["ordered", "blue-noise", "error-diffusion"])
def test_halftoning_happens_on_the_printers_grid_not_on_a_square_one_stretched(slab, tmp_path, method):
    """The J750 stack's droplet masks (halftoned at 600 x 300 dpi) are not the masks of the same layer halftoned at
    600 x 600 dpi and then stretched to 300 dpi by nearest sample; both jet every solid pixel exactly once."""
    preset = printer_preset("j750-27um")
    aniso, _ = slice_to_stack(slab, tmp_path / "a", SliceSpec(layer_height_mm=0.027, dpi=preset.dpi, grade=_grade(),
                                                              channels=True, printer=preset, halftone=method))
    square, _ = slice_to_stack(slab, tmp_path / "q", SliceSpec(layer_height_mm=0.027, dpi=(600.0, 600.0),
                                                               grade=_grade(), channels=True, halftone=method))
    masks = read_layer_channels(tmp_path / "a", aniso, 0)
    fine = read_layer_channels(tmp_path / "q", square, 0)
    assert np.array_equal(masks.sum(axis=0), read_layer_mask(tmp_path / "a", aniso, 0).astype(int))
    rows = sample_indices(square["image"]["height"], square["pixel_size_mm"][1], aniso["pixel_size_mm"][1],
                          aniso["image"]["height"])
    stretched = fine[:, rows, :]
    width = min(stretched.shape[2], masks.shape[2])
    solid = masks[:, :, :width].any(axis=0) & stretched[:, :, :width].any(axis=0)
    differing = (masks[:, :, :width] != stretched[:, :, :width]).any(axis=0) & solid
    assert differing.sum() > 0.05 * solid.sum()


def test_printer_list_and_one_line_errors(tmp_path):
    """``--printer list`` prints the table and exits 0; an unknown preset, and an explicit --dpi or --layer that
    disagrees with the preset, are one line each, exit 2; an agreeing --dpi is accepted."""
    procedural.box((3.0, 2.0, 0.05)).export(tmp_path / "b.ply")
    listed = heoslice("slice", "--printer", "list")
    assert listed.returncode == 0 and "j750-27um" in listed.stdout and "600x300" in listed.stdout
    for extra in (["--printer", "j9"], ["--printer", "j750-27um", "--dpi", "600"],
                  ["--printer", "j750-27um", "--layer", "0.1"]):
        done = heoslice("--no-config", "slice", tmp_path / "b.ply", "-o", tmp_path / "x", *extra)
        assert done.returncode == 2 and done.stderr.count("\n") == 1 and "Traceback" not in done.stderr, done.stderr
    assert in_process("--no-config", "slice", tmp_path / "b.ply", "-o", tmp_path / "ok", "--printer", "j750-27um",
                      "--dpi", "600x300") == 0


def test_the_preset_and_the_halftone_are_settable_in_heoslice_toml(tmp_path):
    """``printer`` and ``halftone`` in heoslice.toml's [slice] act as the options; a toml --layer that disagrees
    with the preset is the one-line error."""
    procedural.box((3.0, 2.0, 0.05)).export(tmp_path / "b.ply")
    config = tmp_path / "heoslice.toml"
    config.write_text('[slice]\nprinter = "j750-27um"\nhalftone = "blue-noise"\n')
    assert in_process("--config", config, "slice", tmp_path / "b.ply", "-o", tmp_path / "s", "--grade", "linear",
                      "--channels") == 0
    import json

    manifest = json.loads((tmp_path / "s" / "manifest.json").read_text())
    assert manifest["dpi"] == [600.0, 300.0] and manifest["grading"]["halftone"] == "blue-noise"
    config.write_text('[slice]\nprinter = "j750-27um"\nlayer = 0.1\n')
    done = heoslice("--config", config, "slice", tmp_path / "b.ply", "-o", tmp_path / "t")
    assert done.returncode == 2 and "--layer" in done.stderr
