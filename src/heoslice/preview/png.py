"""A preview as PNG bytes marked as heoslice's own, and the test for that mark (what ``preview --force`` replaces)."""

from __future__ import annotations

from pathlib import Path

from heoslice.files import head_bytes
from heoslice.pngfile import image_png

#: The PNG text chunk every preview carries (tEXt, before the image data).
SOFTWARE = "heoslice preview"
_MARK = b"tEXtSoftware\x00" + SOFTWARE.encode("ascii")
_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def png_bytes(image) -> bytes:
    """The PIL ``image`` encoded as PNG with the Software text chunk naming heoslice (:mod:`heoslice.pngfile`)."""
    return image_png(image, (("Software", SOFTWARE),))


def is_preview(path: Path) -> bool:
    """Whether ``path`` is a PNG heoslice preview wrote (signature, then the mark among its first chunks)."""
    head = head_bytes(path)
    return head.startswith(_SIGNATURE) and _MARK in head
