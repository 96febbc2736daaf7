"""heoslice's zlib encoders, for the layers' TIFF strips, every PNG and the printer's chunks: a zlib stream
(RFC 1950) at a given level, by zlib-ng (imagecodecs) where this build of imagecodecs has it, else by the standard
library's zlib; or by ISA-L's igzip (isal), the faster on bits like noise (a blue-noise or error-diffusion mask)
at about zlib-ng's level 2 size. Any inflater reads every one; figures in benchmarks/README.md.
"""

from __future__ import annotations

import functools
import zlib
from collections.abc import Callable

#: The encoders by name, each with its levels: zlib-ng's 0-9 (zlib's meaning), ISA-L's 0-3.
ENCODERS = {"zlib-ng": range(10), "isa-l": range(4)}


@functools.cache
def deflater(level: int, encoder: str = "zlib-ng") -> Callable[[bytes], bytes]:
    """bytes -> their zlib stream at ``level`` of ``encoder`` (:data:`ENCODERS`).

    zlib-ng falls back to zlib where imagecodecs lacks it: imagecodecs answers an import of a codec it was built
    without with a placeholder that fails only when called, so zlib-ng's availability is asked, never inferred
    from an import. ISA-L has no fallback: isal is a dependency, and a silent change of encoder would change
    a stack's bytes and hashes."""
    if level not in ENCODERS.get(encoder, ()):
        raise ValueError(f"deflate: no level {level} for encoder {encoder!r} (encoders: {', '.join(ENCODERS)})")
    if encoder == "isa-l":
        from isal import isal_zlib

        return functools.partial(isal_zlib.compress, level=level)
    try:
        import imagecodecs
    except ImportError:
        imagecodecs = None
    codec = getattr(imagecodecs, "ZLIBNG", None)
    if codec is not None and codec.available:
        return functools.partial(imagecodecs.zlibng_encode, level=level)
    return functools.partial(zlib.compress, level=level)
