"""The export sink (heoslice.export.base.Sink): a file added as the same as one written before is a hard link to it
in a folder, a copy where the file system refuses links, and its own entry in a zip; every one reads back its
bytes once the export is in place."""

from __future__ import annotations

import os
import zipfile

from heoslice.export import base
from heoslice.export.base import Sink


def test_a_file_the_same_as_another_is_a_hard_link_to_it_in_a_folder(tmp_path):
    """In a folder, same_as makes one inode of two names (a link, not a second file's bytes); both read back."""
    sink = Sink(tmp_path / "out")
    sink.add("a.png", b"slice bytes")
    sink.add("b.png", b"slice bytes", same_as="a.png")
    sink.add("c.png", b"other")
    sink.commit()
    a, b, c = (os.stat(tmp_path / "out" / name) for name in ("a.png", "b.png", "c.png"))
    assert (a.st_ino, a.st_nlink) == (b.st_ino, 2) and c.st_nlink == 1
    assert (tmp_path / "out" / "b.png").read_bytes() == b"slice bytes"
    assert sink.files == ["a.png", "b.png", "c.png"]


def test_where_links_are_refused_the_file_is_written_as_a_copy(tmp_path, monkeypatch):
    """A file system that refuses hard links (os.link raising OSError, as FAT does) gets the bytes written."""

    def refuse(*args, **kwargs):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(base.os, "link", refuse)
    sink = Sink(tmp_path / "out")
    sink.add("a.png", b"slice bytes")
    sink.add("b.png", b"slice bytes", same_as="a.png")
    sink.commit()
    b = os.stat(tmp_path / "out" / "b.png")
    assert b.st_nlink == 1 and (tmp_path / "out" / "b.png").read_bytes() == b"slice bytes"


def test_in_a_zip_a_file_the_same_as_another_is_its_own_entry(tmp_path):
    """A zip has no links: same_as writes the bytes as an entry of their own."""
    sink = Sink(tmp_path / "out.zip")
    sink.add("a.png", b"slice bytes")
    sink.add("b.png", b"slice bytes", same_as="a.png")
    sink.commit()
    with zipfile.ZipFile(tmp_path / "out.zip") as archive:
        assert archive.read("a.png") == archive.read("b.png") == b"slice bytes"
