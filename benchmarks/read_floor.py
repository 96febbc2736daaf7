"""The least time any command that reads a whole stack can take: every layer file read, hashed and its layout
checked (:func:`heoslice.stack.packed.read_layer_file`), and every strip of a layer's files inflated once (a strip
whose bytes another file of the same layer holds, once for both) into one reused buffer, blank strips (known by
their bytes) not at all, the layers split over the cores in forked processes, nothing else: no counts, no checks
of the pixels, no output. For the 1-bit, deflated files heoslice writes (the benchmark stacks): a grey or colour
file, or strips stored raw, are read and hashed but not decoded, so there it is not a floor. bench_commands.py runs it beside
the commands (``read floor``), so that a command's ratio to the slice can be set against the ratio of the reading
it cannot do without (verify, an x section and a print's dry run read every file and inflate every strip).

Examples:
  python benchmarks/read_floor.py STACK             # prints the files, the strips inflated and the time taken
  python benchmarks/read_floor.py STACK --no-hash   # without the sha256 checks: the reading and inflating alone
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from multiprocessing import get_context
from pathlib import Path


def read_layers(directory: Path, manifest: dict, layers: range, hashed: bool = True) -> tuple[int, int]:
    """(files read, strips inflated) of ``layers``: each file read and checked (its sha256 against the manifest's
    unless not ``hashed``), each distinct strip inflated."""
    import numpy as np

    from heoslice.stack.packed import _BLANK_STRIPS, _plain_strips, _strip_decoder, layer_files

    files = inflated = 0
    buffer = np.empty(0, dtype=np.uint8)
    unhashed = {**manifest, "layers": [{**entry, "sha256": None, "channels": [
        {**channel, "sha256": None} for channel in entry.get("channels") or []]} for entry in manifest["layers"]]}
    for index in layers:
        layer, masks = layer_files(directory, manifest if hashed else unhashed, index)
        seen: set[bytes] = set()
        for file in [layer, *masks]:
            files += 1
            code, view = int(file.page.compression), memoryview(file.data)
            decode = _strip_decoder(code)
            for _, expected, short, offset, count in _plain_strips(file.page) or []:
                strip = bytes(view[offset:offset + count])
                if strip in seen or (short and (code, expected, strip) in _BLANK_STRIPS) or decode is None:
                    continue
                seen.add(strip)
                if len(buffer) < expected + 1:
                    buffer = np.empty(expected + 1, dtype=np.uint8)
                out = decode(strip, out=buffer[:expected + 1])
                inflated += 1
                if short and not np.asarray(out).any():
                    _BLANK_STRIPS.add((code, expected, strip))
    return files, inflated


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("stack", type=Path)
    parser.add_argument("--processes", type=int, default=len(os.sched_getaffinity(0)),
                        help="forked processes the layers are split over [the usable cores]")
    parser.add_argument("--no-hash", action="store_true",
                        help="do not check the files' sha256 (the reading and inflating alone)")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    from heoslice.stack import read_manifest

    manifest = read_manifest(args.stack)
    count = len(manifest["layers"])
    shares = [range(count * k // args.processes, count * (k + 1) // args.processes) for k in range(args.processes)]
    with get_context("fork").Pool(args.processes) as pool:
        done = pool.starmap(read_layers, [(args.stack, manifest, share, not args.no_hash) for share in shares])
    files, inflated = map(sum, zip(*done))
    print(f"{args.stack}: {count} layers, {files} files read and checked{'' if args.no_hash else ' (sha256 too)'}, "
          f"{inflated} strips inflated in {time.perf_counter() - started:.2f} s ({args.processes} processes)")


if __name__ == "__main__":
    sys.exit(main())
