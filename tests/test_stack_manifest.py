"""The manifest schema: the largest stack heoslice writes is one it reads back, verify derives the layer count
and order from required fields alone, and a failed manifest write leaves nothing behind (command line)."""

from __future__ import annotations

import json
import resource
import subprocess
import sys
from pathlib import Path

import pytest

from heoslice import procedural
from heoslice.errors import EXIT_INPUT, EXIT_OUTPUT, EXIT_VERIFY, VerifyError
from heoslice.stack import (
    MAX_LAYERS,
    MAX_MANIFEST_BYTES,
    ChannelRecord,
    ImageRecord,
    LayerRecord,
    build_manifest,
    layer_file_name,
    mask_channels,
    max_layer_count,
    read_manifest,
    write_manifest,
)


def heoslice(*args, limit=None, timeout: float = 60.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "heoslice", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, preexec_fn=limit, stdin=subprocess.DEVNULL)


def one_error(stderr: str) -> str:
    lines = [line for line in stderr.splitlines() if line.strip() and not line.startswith("warning:")]
    assert len(lines) == 1 and lines[0].startswith("heoslice: error:"), stderr
    assert "Traceback" not in stderr and "np." not in stderr
    return lines[0]


@pytest.fixture(scope="module")
def cube_stack(tmp_path_factory) -> Path:
    """A 10 mm cube sliced at 0.5 mm, 50 dpi: 20 layers."""
    folder = tmp_path_factory.mktemp("cube")
    procedural.box().export(folder / "cube.ply")
    done = heoslice("slice", folder / "cube.ply", "--layer", "0.5", "--dpi", "50", "-o", folder / "stack")
    assert done.returncode == 0, done.stderr
    return folder / "stack"


def altered(cube_stack: Path, tmp_path: Path, change) -> Path:
    """A copy of the cube stack whose manifest (and files) ``change(directory, manifest)`` altered."""
    directory = tmp_path / "altered"
    directory.mkdir()
    for item in cube_stack.iterdir():
        (directory / item.name).write_bytes(item.read_bytes())
    manifest = json.loads((directory / "manifest.json").read_text())
    change(directory, manifest)
    (directory / "manifest.json").write_text(json.dumps(manifest, indent=1))
    return directory


@pytest.mark.parametrize("channels", [(), ("gel", "cells"), tuple(f"material-{n:02d}-\u00fcber" for n in range(8))])
def test_largest_stack_heoslice_writes_is_one_it_reads(tmp_path, channels):
    """A manifest of max_layer_count layers, every field at its longest, is written and read back; the limit
    never exceeds MAX_LAYERS and shrinks with droplet masks."""
    count = max_layer_count(channels)
    assert 1000 < count <= MAX_LAYERS and (count < MAX_LAYERS) == bool(channels)
    name = "x" * 40
    layer = LayerRecord(-1.2345678901234567e-300, "f" * 64, 1 << 30, True,
                        tuple(ChannelRecord(m, layer_file_name(count, m.encode("ascii", "replace").decode()),
                                            "f" * 64, 1 << 30) for m in channels) or None)
    manifest = build_manifest(source_file=name, source_sha256="0" * 64, layer_height_mm=0.001, dpi=(600.0, 600.0),
                              pixel_size_mm=(25.4 / 600, 25.4 / 600),
                              image=ImageRecord(32768, 32768, (-1.2345678901234567e-300, 1e-300), "1", "deflate"),
                              z_range_mm=(0.0, 1.0), warnings=["w" * 200] * 10, layers=[layer] * count)
    manifest["layers"][-1]["z_mm"] = -1.2345678901234567e-300
    write_manifest(tmp_path, manifest)
    assert (tmp_path / "manifest.json").stat().st_size <= MAX_MANIFEST_BYTES
    assert len(read_manifest(tmp_path)["layers"]) == count


def test_more_layers_than_a_stack_holds_is_refused_before_slicing(tmp_path):
    """A 100 mm pillar at --layer 0.001 (100,000 layers) is refused in one line, exit 2, before any layer
    is written (it used to write a stack that verify then refused)."""
    procedural.box(extents=(2.0, 2.0, 100.0)).export(tmp_path / "pillar.ply")
    done = heoslice("slice", tmp_path / "pillar.ply", "--layer", "0.001", "--dpi", "50", "-o", tmp_path / "s",
                    timeout=30)
    assert done.returncode == EXIT_INPUT and "more than 50000 layers" in one_error(done.stderr), done.stderr
    assert not list((tmp_path / "s").glob("layer_*")) if (tmp_path / "s").exists() else True


def test_verify_catches_a_stack_cut_short_without_z_range(cube_stack, tmp_path):
    """z_range_mm deleted and the last five layers removed (entries and files): verify fails, exit 4."""
    def cut(directory, manifest):
        del manifest["z_range_mm"]
        for entry in manifest["layers"][-5:]:
            (directory / entry["file"]).unlink()
        del manifest["layers"][-5:]

    assert heoslice("verify", cube_stack).returncode == 0
    done = heoslice("verify", altered(cube_stack, tmp_path, cut))
    assert done.returncode == EXIT_VERIFY and "z_range_mm" in done.stdout + done.stderr


def test_verify_catches_a_stack_cut_short(cube_stack, tmp_path):
    """The last five layers removed, z_range_mm kept: verify fails naming the layer count, exit 4."""
    def cut(directory, manifest):
        for entry in manifest["layers"][-5:]:
            (directory / entry["file"]).unlink()
        del manifest["layers"][-5:]

    done = heoslice("verify", altered(cube_stack, tmp_path, cut))
    assert done.returncode == EXIT_VERIFY and "15 layers" in done.stdout and "needs 20" in done.stdout


@pytest.mark.parametrize("keep_range", [True, False])
def test_verify_catches_layers_out_of_order(cube_stack, tmp_path, keep_range):
    """Two layers' z_mm swapped (with or without z_range_mm): verify fails, exit 4, no numpy repr shown."""
    def swap(directory, manifest):
        layers = manifest["layers"]
        layers[3]["z_mm"], layers[7]["z_mm"] = layers[7]["z_mm"], layers[3]["z_mm"]
        if not keep_range:
            del manifest["z_range_mm"]

    done = heoslice("verify", altered(cube_stack, tmp_path, swap))
    assert done.returncode == EXIT_VERIFY and "np." not in done.stdout
    assert ("layer 3: z_mm" in done.stdout) if keep_range else ("z_range_mm" in done.stdout + done.stderr)


def test_full_disk_at_the_manifest_leaves_no_temporary_file(tmp_path):
    """When the file size limit is hit writing the manifest (every layer fits, the manifest does not): one
    line, exit 3, and neither manifest.json nor manifest.json.tmp is left."""
    procedural.box().export(tmp_path / "cube.ply")

    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (2500, 2500))

    done = heoslice("slice", tmp_path / "cube.ply", "--layer", "0.25", "--dpi", "20", "-o", tmp_path / "s",
                    "-j", "1", limit=limit)
    assert done.returncode == EXIT_OUTPUT and "manifest.json" in one_error(done.stderr), done.stderr
    assert len(list((tmp_path / "s").glob("layer_*.tif"))) == 40
    assert not (tmp_path / "s" / "manifest.json").exists()
    assert not (tmp_path / "s" / "manifest.json.tmp").exists()


def manifest_of(*materials: tuple[str, int | None]) -> dict:
    """A manifest with one layer whose droplet masks are of ``materials`` ((name, channel) pairs)."""
    return {"layers": [{"channels": [{"material": name, "file": f"{name}.tif"} for name, _ in materials]}],
            "grading": {"materials": [{"name": name, "channel": channel} for name, channel in materials]}}


@pytest.mark.parametrize("materials, channels", [
    ((("a", 2), ("b", 1)), (2, 1)),
    ((("a", None), ("b", None), ("c", None)), (1, 2, 3)),
    ((("a", None), ("b", 1), ("c", None)), (2, 1, 3)),
    ((("a", 4), ("b", None)), (4, 1)),
])
def test_mask_channels_names_and_fills(materials, channels):
    """A named channel is kept; masks whose materials name none take the lowest channels nobody names, in
    order (all unnamed: 1..K as listed)."""
    assert mask_channels(manifest_of(*materials)) == channels


def test_mask_channels_without_grading_is_the_list_order():
    """A stack whose masks have no grading.materials (hand-made) is sent on 1..K in its layers' order; one
    without layers or masks has no mask channels."""
    manifest = {"layers": [{"channels": [{"file": "x.tif"}, {"file": "y.tif"}]}, {"channels": []}]}
    assert mask_channels(manifest) == (1, 2)
    assert mask_channels({"layers": []}) == mask_channels({"layers": [{}], "grading": None}) == ()


def test_mask_channels_refuses_two_masks_on_one_channel():
    """Two masks naming one printer channel: a one-line VerifyError naming the stack and both materials, not
    a guess (the structure of grading.materials is manifest_problem's, tests/test_stack.py)."""
    with pytest.raises(VerifyError, match="a, b all name printer channel 2") as caught:
        mask_channels(manifest_of(("a", 2), ("b", 2), ("c", None)), "some_stack")
    assert str(caught.value).startswith("some_stack: ") and "\n" not in str(caught.value)


@pytest.mark.parametrize("change, problem", [
    (lambda m: m.update(scale=0), "'scale' must be a positive number"),
    (lambda m: m.update(scale="1000"), "'scale' must be a positive number"),
    (lambda m: m.update(parts=[{"name": "a", "volume_mm3": -1.0}]), "parts[0]: 'volume_mm3' must be a number >= 0"),
    (lambda m: m.update(parts=[{"name": "a", "volume_mm3": "12"}]), "parts[0]: 'volume_mm3' must be a number >= 0"),
])
def test_the_recorded_scale_and_part_volumes_are_checked(cube_stack, change, problem):
    """The manifest's 'scale' (a positive number) and parts' 'volume_mm3' (a number >= 0 or null) are checked
    by the one manifest check; a stack without them (written before they were recorded) is read."""
    from heoslice.stack import manifest_problem

    manifest = read_manifest(cube_stack)
    assert manifest["scale"] == 1.0 and manifest_problem(manifest) is None
    old = {key: value for key, value in manifest.items() if key != "scale"}
    assert manifest_problem(old) is None
    assert manifest_problem({**manifest, "parts": [{"name": "a", "volume_mm3": None}]}) is None
    change(manifest)
    assert problem in manifest_problem(manifest)


@pytest.mark.parametrize("method", ["ordered", "blue-noise", "error-diffusion"])
def test_the_manifest_records_the_halftone_and_verify_accepts_every_method(tmp_path, method):
    """A droplet-mask stack records its halftone (ordered: no field, as every stack before the choice) and passes
    verify whatever the method; a manifest naming an unknown method is refused by every reader."""
    from heoslice.grading import GradeSpec, RegionSpec
    from heoslice.material import DEFAULT_MATERIALS, make_function
    from heoslice.mesh import load_mesh
    from heoslice.pipeline import SliceSpec, slice_to_stack
    from heoslice.stack import manifest_problem, verify_stack

    procedural.box((4.0, 3.0, 1.0)).export(tmp_path / "b.ply")
    grade = GradeSpec(RegionSpec(nozzle_mm=0.4), make_function("linear"), DEFAULT_MATERIALS["M2"], None,
                      DEFAULT_MATERIALS["M1"], DEFAULT_MATERIALS["M2"])
    manifest, _ = slice_to_stack(load_mesh(tmp_path / "b.ply"), tmp_path / "s",
                                 SliceSpec(layer_height_mm=0.5, dpi=(200.0, 200.0), grade=grade, channels=True,
                                           halftone=method))
    assert manifest["grading"].get("halftone", "ordered") == method
    assert ("halftone" in manifest["grading"]) == (method != "ordered")
    assert verify_stack(tmp_path / "s").ok
    manifest["grading"]["halftone"] = "floyd"
    assert "grading.halftone" in manifest_problem(manifest)
