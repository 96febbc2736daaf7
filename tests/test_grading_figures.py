"""The paper's figure scripts (examples/fig3.py, fig9.py) run small, write their PNGs and say what they reproduce."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from PIL import Image

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


@pytest.mark.parametrize("script, says", [("fig3.py", ["Fig. 3 (a, b): layer 360", "360 intersection points",
                                                       "200 offsets to (0, 255, 0)", "Fig. 3 (c)"]),
                                          ("fig9.py", ["Fig. 9: layer 83 of a 0.1 mm", "liver phantom with a lesion",
                                                       "of the organ and 1 of the lesion", "(a) without, (b) with"])])
def test_figure_script_writes_its_png_and_states_what_it_reproduces(tmp_path, script, says):
    """With --small the script writes a PNG of its panels side by side and prints which layer, settings and
    figure it reproduces (the vase's 360th layer with its 360 points; layer 83 of the 0.1 mm liver stack)."""
    out = tmp_path / "figure.png"
    done = subprocess.run([sys.executable, str(EXAMPLES / script), str(out), "--small"], capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    for phrase in says:
        assert phrase in done.stdout, (phrase, done.stdout)
    with Image.open(out) as image:
        assert image.size[0] > 2 * 240
