"""Tests of cli/material_report.py: the design verify --design PREVIEW compares is a share of the material the
stack's manifest records as the grading's target, in either order of --from and --to."""

from __future__ import annotations

import json

import numpy as np
import pytest

from heoslice import procedural
from heoslice.stack import read_manifest
from heoslice.stack.read import read_layer_mask
from heoslice.stack.report import material_names, preview_design


@pytest.fixture(scope="module")
def vase(tmp_path_factory):
    folder = tmp_path_factory.mktemp("roles")
    procedural.vase().export(folder / "vase.ply")
    return folder


@pytest.mark.parametrize("start, target", [("M1", "M2"), ("M2", "M1")])
def test_the_design_is_a_share_of_the_recorded_target(vase, run_cli, start, target):
    """A vase graded --from START --to TARGET (droplet masks, and its --rgba preview as the design): verify's JSON
    names TARGET (the manifest's grading.target) as the design's target and as what every band's designed share is
    of, each band holds the pixels whose designed TARGET share is in it (the preview's colour read out here), and
    the text names TARGET in the band lines."""
    from helpers import in_process

    stack, preview = vase / f"{start}-{target}", vase / f"{start}-{target}-rgba"
    for output, extra in ((stack, []), (preview, ["--rgba"])):
        assert in_process("slice", vase / "vase.ply", "--grade", "linear", "--from", start, "--to", target,
                          "--layer", "5", "--dpi", "100", "-j", "1", "-o", output, *extra) == 0
    manifest = read_manifest(stack)
    assert manifest["grading"]["target"]["name"] == target
    code, out, err = run_cli("verify", stack, "--design", preview, "--json")
    delivered = json.loads(out)["delivered"]
    assert delivered["design"] == {"from": "preview", "bands_of": "share", "target": target}
    assert delivered["bands"] and {band["designed_share_of"] for band in delivered["bands"]} == {target}
    names = material_names(manifest)
    design = preview_design(preview, manifest, [m["color"] for m in manifest["grading"]["materials"]],
                            read_manifest(preview))
    share = np.concatenate([design(index)[names.index(target)][read_layer_mask(stack, manifest, index)]
                            for index in range(len(manifest["layers"]))])
    for band in delivered["bands"]:
        inside = np.minimum((share * 10).astype(int), 9) == round(10 * band["band"][0])
        assert band["voxels"] == int(inside.sum())
        assert band["designed"][target] == pytest.approx(float(share[inside].mean()), abs=1e-6)
    code, out, err = run_cli("verify", stack, "--design", preview)
    bands = [line for line in out.splitlines() if line.startswith("  designed ")]
    assert bands and all(line.startswith(f"  designed {target} ") for line in bands), out
