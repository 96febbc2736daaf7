"""heoslice's one zlib encoder, for the layers' TIFF strips, every PNG and the printer's chunks: a zlib stream
(RFC 1950) at a given level by zlib-ng (imagecodecs) where this build of imagecodecs has it, else by the standard
library's zlib. Any inflater reads either; zlib-ng is the faster on 1-bit masks (figures in benchmarks/README.md).
"""

from __future__ import annotations

import functools
import zlib
from collections.abc import Callable


@functools.cache
def deflater(level: int) -> Callable[[bytes], bytes]:
    """bytes -> their zlib stream at ``level``. imagecodecs answers an import of a codec it was built without with
    a placeholder that fails only when called, so zlib-ng's availability is asked, never inferred from an import."""
    try:
        import imagecodecs
    except ImportError:
        imagecodecs = None
    codec = getattr(imagecodecs, "ZLIBNG", None)
    if codec is not None and codec.available:
        return functools.partial(imagecodecs.zlibng_encode, level=level)
    return functools.partial(zlib.compress, level=level)
