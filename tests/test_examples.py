"""The README's pictures are committed files, and the example scripts that draw them run and write a picture
(issues 44 and 48: a section of each interior, each halftoning method)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
from PIL import Image

REPO = Path(__file__).resolve().parents[1]
PICTURE = re.compile(r"!\[[^\]]*\]\(([^)\s]+)\)")


def test_every_picture_the_readme_shows_is_in_the_repository():
    pictures = PICTURE.findall((REPO / "README.md").read_text())
    assert {"examples/interiors.png", "examples/halftones.png"} <= set(pictures), pictures
    for picture in pictures:
        assert (REPO / picture).is_file(), picture
        if (REPO / ".git").exists():
            tracked = subprocess.run(["git", "-C", str(REPO), "ls-files", "--error-unmatch", picture],
                                     capture_output=True)
            assert tracked.returncode == 0, f"{picture} is not committed"


@pytest.mark.parametrize("script, options", [("interiors.py", ["--dpi", "60", "--layer", "0.5", "--size", "80"]),
                                             ("halftones.py", ["--width", "64", "--height", "16"])])
def test_example_script_writes_its_picture(script, options, tmp_path):
    out = tmp_path / "picture.png"
    done = subprocess.run([sys.executable, str(REPO / "examples" / script), str(out), *options],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    with Image.open(out) as image:
        assert image.width > 0 and image.height > 0
