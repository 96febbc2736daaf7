"""The resource model of mesh reading: every size a file declares is checked against a limit before use.

Work and memory of loading grow with the file's size and with the counts it declares,
both bounded here, so no file makes heoslice allocate or loop beyond these limits:

- a mesh file is at most MAX_MESH_BYTES (OBJ and ASCII STL, parsed by trimesh, at most
  MAX_TRIMESH_BYTES), refused from its size before it is read; a file with holes
  (sparse) is refused, since its size vouches for nothing;
- at most MAX_VERTICES vertices and MAX_TRIANGLES triangles (after polygons are
  fan-triangulated), and at most MAX_TRIANGLES rows in any PLY element, refused from the
  header or the polygon sizes before the arrays are made;
- an ASCII body (PLY, OFF) holds on average at most TEXT_BYTES_PER_ROW bytes per row it
  declares, plus TEXT_SLACK_BYTES, and at most twice as many lines as rows plus
  TEXT_SLACK_LINES: blank-line and comment floods are refused from the counts.
"""

from __future__ import annotations

from pathlib import Path

from heoslice.errors import InputError

MAX_MESH_BYTES = 4 << 30
MAX_TRIMESH_BYTES = 512 << 20
MAX_VERTICES = 1 << 25
MAX_TRIANGLES = 1 << 25
TEXT_BYTES_PER_ROW = 1024
TEXT_SLACK_BYTES = 1 << 20
TEXT_SLACK_LINES = 10_000


def check_count(path: Path, what: str, count: int, limit: int) -> None:
    """InputError when a file declares more ``what`` (e.g. 'vertices') than ``limit``."""
    if count > limit:
        raise InputError(f"{path}: declares {count} {what}, more than the {limit} heoslice reads")


def check_text_body(path: Path, body_bytes: int, rows: int, lines: int | None = None) -> None:
    """InputError when an ASCII body of ``body_bytes`` bytes (and ``lines`` lines) is far larger than its ``rows``.

    Checked before the body is tokenised, so a flood of blank lines, spaces or comments
    costs one count, not arrays the size of the flood.
    """
    allowed = TEXT_BYTES_PER_ROW * rows + TEXT_SLACK_BYTES
    if body_bytes > allowed:
        raise InputError(f"{path}: text body of {body_bytes} bytes for {rows} declared rows (at most "
                         f"{TEXT_BYTES_PER_ROW} bytes per row on average plus {TEXT_SLACK_BYTES} are read): "
                         "blank lines, spaces or comments flood the file")
    if lines is not None and lines > 2 * rows + TEXT_SLACK_LINES:
        raise InputError(f"{path}: {lines} lines for {rows} declared rows (at most {2 * rows + TEXT_SLACK_LINES} "
                         "are read): blank or comment lines flood the file")
