"""`heoslice export --format gcvf`: one zip of layer_N.png (from 0, one colour per material) and ConfigFile.xml
(resolution, slice thickness in nm, bit depth, colours, each material's RGBA and voxel count from the masks);
at most 6 materials; clear refusals."""

from __future__ import annotations

import io
import xml.etree.ElementTree as ET
import zipfile

import numpy as np
import pytest
from PIL import Image

from heoslice import procedural
from heoslice.errors import InputError
from heoslice.export import ExportOptions, export_stack
from heoslice.export import gcvf
from heoslice.grading import GradeSpec, RegionSpec
from heoslice.material import DEFAULT_MATERIALS, Material, make_function
from heoslice.mesh import load_mesh
from heoslice.pipeline import SliceSpec, slice_to_stack
from heoslice.pipeline.printers import printer_preset


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    """A 3-material graded slab (M1, M2 and blue) sliced with the J750 preset."""
    folder = tmp_path_factory.mktemp("gcvf")
    procedural.box((5.0, 4.0, 0.08)).export(folder / "slab.ply")
    grade = GradeSpec(RegionSpec(nozzle_mm=0.3), make_function("linear"), Material("blue", (0, 0, 255)), None,
                      DEFAULT_MATERIALS["M1"], DEFAULT_MATERIALS["M2"])
    preset = printer_preset("j750-27um")
    manifest, _ = slice_to_stack(load_mesh(folder / "slab.ply"), folder / "stack",
                                 SliceSpec(layer_height_mm=preset.layer_mm, dpi=preset.dpi, grade=grade, channels=True,
                                           printer=preset, halftone="error-diffusion"))
    assert len(manifest["grading"]["materials"]) == 3
    return folder / "stack", manifest


def test_gcvf_holds_numbered_layers_and_a_config_whose_voxel_counts_are_the_masks(stack, tmp_path):
    """layer_0.png .. layer_{n-1}.png and ConfigFile.xml; 600 x 300 dpi, 27000 nm, the slice size and count, bit
    depth and colours; per material its RGBA and a voxel count equal to its masks' pixels over the stack; each
    layer's pixels only the background and the materials' colours, each colour's pixels the material's mask."""
    directory, manifest = stack
    out = tmp_path / "slab.gcvf"
    summary = export_stack(directory, "gcvf", out)
    with zipfile.ZipFile(out) as archive:
        names = archive.namelist()
        layers = len(manifest["layers"])
        assert sorted(names) == sorted([f"layer_{n}.png" for n in range(layers)] + ["ConfigFile.xml"])
        config = ET.fromstring(archive.read("ConfigFile.xml"))
        images = [np.asarray(Image.open(io.BytesIO(archive.read(f"layer_{n}.png")))) for n in range(layers)]
    assert config.findtext("Resolution/XDpi") == "600" and config.findtext("Resolution/YDpi") == "300"
    assert config.findtext("Resolution/SliceThicknessNanoMeter") == "27000"
    assert config.findtext("SliceRange/NumberOfSlices") == str(layers)
    assert config.findtext("SliceDimensions/SliceWidth") == str(manifest["image"]["width"])
    assert config.findtext("BitDepth") == str(gcvf.BIT_DEPTH)
    assert config.findtext("MaxNumberOfColors") == "6"
    materials = config.findall("MaterialList/Material")
    recorded = manifest["grading"]["materials"]
    assert [m.findtext("Name") for m in materials] == [m["name"] for m in recorded]
    for number, (material, record) in enumerate(zip(materials, recorded)):
        rgba = [int(v) for v in material.findtext("RGBA").split()]
        assert rgba == [*record["color"], 255]
        in_masks = sum(entry["channels"][number]["solid_pixels"] for entry in manifest["layers"])
        assert int(material.findtext("VoxelCount")) == in_masks
        assert sum((image == rgba).all(axis=2).sum() for image in images) == in_masks
    assert sum(int(m.findtext("VoxelCount")) for m in materials) > 0
    allowed = {(0, 0, 0, 255), *(tuple([*m["color"], 255]) for m in recorded)}
    assert {tuple(v) for image in images for v in np.unique(image.reshape(-1, 4), axis=0)} <= allowed
    assert summary["slices"] == layers


def test_more_than_six_materials_and_a_folder_output_are_one_line_refusals(stack, tmp_path, monkeypatch):
    """A stack of more materials than a .gcvf carries is refused naming the limit (here the limit lowered to 2 for
    the 3-material stack), and so is an output that is not a .gcvf (or .zip) file; nothing is left behind."""
    directory, _ = stack
    monkeypatch.setattr(gcvf, "MAX_MATERIALS", 2)
    with pytest.raises(InputError, match="at most 2 materials"):
        export_stack(directory, "gcvf", tmp_path / "x.gcvf")
    monkeypatch.undo()
    with pytest.raises(InputError, match=r"\.gcvf"):
        export_stack(directory, "gcvf", tmp_path / "folder")
    with pytest.raises(InputError, match="background"):
        export_stack(directory, "gcvf", tmp_path / "y.gcvf", ExportOptions(background=(1, 2, 3)))
    assert sorted(p.name for p in tmp_path.iterdir()) == []
