"""Tests of printing/job.py: a stack as a print job, each droplet mask on the printer channel its material
names in the manifest (not its place in the list)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import tifffile
from helpers import executed_on_simulator, in_process

from heoslice import procedural
from heoslice.printing import stack_job
from heoslice.printing import protocol as P

#: gel is the table's first material (M1, the contour's) on printer channel 3, cells (M2, --to) on channel 1.
MATERIALS = '[materials.gel]\ncolor = "#f0f0f0"\nchannel = 3\n\n[materials.cells]\ncolor = "0,255,0"\nchannel = 1\n'


@pytest.fixture(scope="module")
def graded_stack(tmp_path_factory) -> Path:
    """A box graded from gel to cells, sliced by `heoslice slice` with the materials file above."""
    folder = tmp_path_factory.mktemp("channels")
    model = folder / "box.ply"
    model.write_bytes(procedural.box((8.0, 6.0, 3.0)).export(file_type="ply", encoding="binary"))
    (folder / "mats.toml").write_text(MATERIALS)
    assert in_process("slice", model, "--materials", folder / "mats.toml", "--grade", "linear", "--to", "cells",
                      "--nozzle", "0.5", "--layer", "1", "--dpi", "100", "-j", "1", "-o", folder / "stack") == 0
    return folder / "stack"


def test_each_mask_goes_on_the_channel_its_material_names(graded_stack):
    """The manifest lists gel (channel 3) before cells (channel 1): the job has channels 0..3, the solid mask on
    0, cells' mask on 1, nothing on 2, gel's on 3; the simulated controller executes every layer once with the
    CRC of exactly that layout, read back from the TIFFs."""
    manifest = json.loads((graded_stack / "manifest.json").read_text())
    assert [(m["name"], m["channel"]) for m in manifest["grading"]["materials"]] == [("gel", 3), ("cells", 1)]
    job, get_layer = stack_job(graded_stack)
    assert job.channels == 4 and job.names == ("solid", "cells", "unused", "gel")
    expected = []
    for entry in manifest["layers"]:
        read = {"solid": tifffile.imread(graded_stack / entry["file"]).astype(bool)}
        read.update({c["material"]: tifffile.imread(graded_stack / c["file"]).astype(bool) for c in entry["channels"]})
        assert read["gel"].any() and read["cells"].any()
        layout = [read["solid"], read["cells"], np.zeros_like(read["solid"]), read["gel"]]
        expected.append(b"".join(np.packbits(mask, axis=1).tobytes() for mask in layout))
        assert b"".join(get_layer(entry["index"])) == expected[-1]
    executed = executed_on_simulator(job, get_layer)
    assert [e.crc for e in executed] == [P.crc32(data) for data in expected]




def test_layer_map_runs_layers_in_order_in_batches_over_workers():
    """layer_map yields function(layer) for every layer in order, whether the layers go one a task (few layers)
    or in runs of up to BATCH_LAYERS (thousands), computed in workers."""
    import os

    from heoslice.printing.job import layer_map

    for count in (5, 3000):
        results = list(layer_map(lambda layer: (layer * 3, os.getpid()), range(count), workers=2))
        assert [value for value, _ in results] == [3 * layer for layer in range(count)]
        assert os.getpid() not in {pid for _, pid in results}
