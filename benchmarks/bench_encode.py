"""Size and time of a stack's 1-bit files re-encoded at each deflate level, and the cost of laying a file
out from its recalled layout against tifffile writing it (the figures behind stack/tiff.py's choices).

Reads every ``--every``-th layer of STACK (its solid layers and, per material, its droplet masks),
re-encodes each at zlib levels 1-5 (of each of ``--encoders``) with :func:`heoslice.stack.encode_bilevel_tiff`
(best of ``--repeats``) and prints the mean size and time per file; then times one solid layer through
tifffile.imwrite from the same strips against the recalled layout, alternating. ``--codecs`` adds, per
kind of file (solid, each material's masks), whole-file sizes under other lossless codecs (imagecodecs'),
to see how small any codec gets a dithered mask, and the smallest a layer gets with each file in its best
codec (also with the last mask implied by the others), against a PrusaSlicer .sl1 of the job (``--sl1``).
``--labels MESH`` adds the same layers' per-pixel sub-region labels, recomputed from the job's mesh (0 off the
solid), under the same codecs: what a stack holding labels instead of droplet masks would take.

Examples:
  heoslice slice liver.ply --grade linear --to 0,255,0 --channels -o liver_stack
  python benchmarks/bench_encode.py liver_stack
  python benchmarks/bench_encode.py liver_stack --every 10 --levels 1,2,6
  python benchmarks/bench_encode.py liver_stack --every 1 --levels 1,2 --encoders zlib-ng,isa-l --cpu
  python benchmarks/bench_encode.py liver_stack --every 50 --codecs --sl1 liver.sl1
  python benchmarks/bench_encode.py liver_stack --every 50 --codecs --sl1 liver.sl1 --labels liver.ply
"""

from __future__ import annotations

import argparse
import io
import time
import zipfile
from pathlib import Path

import numpy as np
import tifffile

from heoslice.stack import encode_bilevel_tiff, read_manifest
from heoslice.stack.tiff import COMPRESSIONS, _strip_codec, calibration


def best_of(repeats: int, work, clock=time.perf_counter) -> float:
    """The fastest of ``repeats`` runs of ``work()``, s by ``clock`` (wall time unless told)."""
    times = []
    for _ in range(repeats):
        started = clock()
        work()
        times.append(clock() - started)
    return min(times)


def by_tifffile(packed: np.ndarray, width: int, dpi, spacing) -> bytes:
    """tifffile.imwrite's file of the same deflate strips (the layout's baseline)."""
    codec = _strip_codec("deflate", 1)
    strips = [codec(packed[row:row + 256].tobytes()) for row in range(0, len(packed), 256)]
    buffer = io.BytesIO()
    tifffile.imwrite(buffer, data=iter(strips), shape=(len(packed), width), dtype=bool,
                     compression=COMPRESSIONS["deflate"], photometric="miniswhite", rowsperstrip=256,
                     software="bench", **calibration(dpi, spacing))
    return buffer.getvalue()


def job_labels(mesh_path: Path, manifest: dict, entries: list[dict]) -> list[np.ndarray]:
    """The sub-region labels of the given layers of a graded stack's job ((height, width) uint, 0 off the solid),
    recomputed from its mesh with :func:`heoslice.grading.layer_regions` on the stack's own grid."""
    from bench_grading import layer_inputs

    from heoslice.grading import layer_regions
    from heoslice.grading.spec import RegionSpec
    from heoslice.layers.contours import build_contours
    from heoslice.layers.rasterising import Grid, packed_mask
    from heoslice.layers.slicing import slice_mesh
    from heoslice.mesh.load import load_mesh

    grading, image = manifest["grading"], manifest["image"]
    spec = RegionSpec(nozzle_mm=grading["nozzle_mm"], depth_mm=grading["depth_mm"], direction=grading["direction"],
                      count=grading["offsets"])
    (px, py), (x_left, y_top) = manifest["pixel_size_mm"], image["origin_mm"]
    grid = Grid(width=image["width"], height=image["height"], x_left=x_left, y_top=y_top, px=px, py=py)
    mesh = load_mesh(mesh_path)
    contours = build_contours(slice_mesh(mesh.vertices, mesh.faces, np.array([e["z_mm"] for e in entries])))
    labels = []
    for index in range(len(entries)):
        points, offsets, area, parent = layer_inputs(contours, index)
        packed = packed_mask(points, offsets, grid)
        regions = layer_regions(points, offsets, area, parent, None, grid, spec, packed)
        r0, r1, c0, c1 = regions.box
        label = np.zeros((grid.height, grid.width), dtype=regions.label.dtype)
        label[r0:r1, c0:c1] = regions.label
        label[~np.unpackbits(packed, axis=1, count=grid.width).view(bool)] = 0
        labels.append(label)
    return labels


def codec_survey(kinds: dict[str, list[np.ndarray]], width: int,
                 labels: list[np.ndarray] = ()) -> dict[str, dict[str, float]]:
    """Mean size (bytes) and time (s) a file of each codec, per kind of file (solid, each material's masks),
    over whole packed masks (no strips, no TIFF), printed as it goes, and of the ``labels`` (whole images of
    sub-region labels) where given; returns {kind: {codec: bytes}}."""
    import imagecodecs

    def grey(p: np.ndarray) -> np.ndarray:
        return np.unpackbits(p, axis=1, count=width) * np.uint8(255)

    codecs = {
        "zlib-ng 2 (the stack's)": lambda p: imagecodecs.zlibng_encode(p.tobytes(), level=2),
        "zlib-ng 9": lambda p: imagecodecs.zlibng_encode(p.tobytes(), level=9),
        "zstd 3": lambda p: imagecodecs.zstd_encode(p.tobytes(), level=3),
        "zstd 19": lambda p: imagecodecs.zstd_encode(p.tobytes(), level=19),
        "lzma 6": lambda p: imagecodecs.lzma_encode(p.tobytes()),
        "brotli 5": lambda p: imagecodecs.brotli_encode(p.tobytes(), level=5),
        "webp lossless 6": lambda p: imagecodecs.webp_encode(np.repeat(grey(p)[..., None], 3, axis=2),
                                                             lossless=True, level=6),
        "jpeg-xl lossless e7": lambda p: imagecodecs.jpegxl_encode(grey(p), lossless=True, effort=7),
    }
    sizes: dict[str, dict[str, float]] = {}
    for kind, packed in kinds.items():
        print(f"  whole {kind} files under other codecs:")
        for name, encode in codecs.items():
            started = time.perf_counter()
            size = float(np.mean([len(encode(p)) for p in packed]))
            sizes.setdefault(kind, {})[name] = size
            print(f"    {name:24s} {size / 1024:7.1f} KB  {(time.perf_counter() - started) / len(packed) * 1e3:7.1f} ms")
    if len(labels):
        print(f"  the sub-region labels ({labels[0].dtype}, up to {max(int(a.max()) for a in labels)}), whole images:")
        label_codecs = {name: codecs[name] for name in ("zlib-ng 9", "zstd 19", "lzma 6")}
        label_codecs["png 9"] = lambda a: imagecodecs.png_encode(a, level=9)
        for name, encode in label_codecs.items():
            size = float(np.mean([len(encode(a)) for a in labels]))
            sizes.setdefault("labels", {})[name] = size
            print(f"    {name:24s} {size / 1024:7.1f} KB")
    return sizes


def best_layer(sizes: dict[str, dict[str, float]], sl1: Path | None) -> None:
    """The smallest a layer gets with each file in its best codec: all files, and with the last material's mask
    left out (it is the solid pixels no other mask has); against an .sl1's mean compressed layer PNG."""
    best = {kind: min(by_codec.values()) for kind, by_codec in sizes.items() if kind != "labels"}
    masks = [kind for kind in best if kind != "solid"]
    rows = {"every file": sum(best.values()),
            "the last mask implied": sum(best.values()) - (best[masks[-1]] if masks else 0.0)}
    if "labels" in sizes:
        rows["the labels instead of the masks"] = best["solid"] + min(sizes["labels"].values())
    reference = None
    if sl1 is not None:
        with zipfile.ZipFile(sl1) as archive:
            pngs = [info.compress_size for info in archive.infolist() if info.filename.endswith(".png")
                    and not info.filename.startswith("thumbnail")]
        reference = float(np.mean(pngs))
        print(f"  {sl1.name}: {reference / 1024:.1f} KB a layer PNG ({len(pngs)} layers)")
    for name, size in rows.items():
        ratio = f", {size / reference:.2f}x the .sl1's" if reference else ""
        print(f"  a layer, each file in its best codec, {name}: {size / 1024:.1f} KB{ratio}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="\n".join(__doc__.split("\n\n")[-1:]))
    parser.add_argument("stack", type=Path)
    parser.add_argument("--every", type=int, default=25, help="take every N-th layer [25]")
    parser.add_argument("--levels", default="1,2,3,4,5", help="zlib levels [1,2,3,4,5]")
    parser.add_argument("--encoders", default="zlib-ng",
                        help="comma-separated deflate encoders, each at every level (heoslice.deflate.ENCODERS: "
                             "zlib-ng, isa-l; isa-l's levels are 0-3) [zlib-ng]")
    parser.add_argument("--repeats", type=int, default=3, help="runs per figure, best taken [3]")
    parser.add_argument("--cpu", action="store_true",
                        help="time the levels in CPU seconds of this process, which other work on the machine "
                             "inflates less than wall time")
    parser.add_argument("--codecs", action="store_true", help="also whole-file sizes under other codecs")
    parser.add_argument("--sl1", type=Path, default=None,
                        help="with --codecs: a PrusaSlicer .sl1 of the same job, to compare a layer's best size with")
    parser.add_argument("--labels", type=Path, default=None, metavar="MESH",
                        help="with --codecs: the job's mesh, to size its sub-region labels too")
    args = parser.parse_args(argv)
    manifest = read_manifest(args.stack)
    width, dpi, spacing = manifest["image"]["width"], tuple(manifest["dpi"]), manifest["layer_height_mm"]
    kinds: dict[str, list[np.ndarray]] = {}
    for entry in manifest["layers"][::args.every]:
        files = [("solid", entry["file"])] + [(channel["material"], channel["file"])
                                              for channel in entry.get("channels", [])]
        for kind, name in files:
            bits = tifffile.imread(args.stack / name).astype(bool)
            kinds.setdefault(kind, []).append(np.packbits(bits, axis=1))
    print(f"{args.stack}: {width} px wide, every {args.every}th layer")
    ways = [(encoder, int(level)) for encoder in args.encoders.split(",") for level in args.levels.split(",")]
    for kind, layers in kinds.items():
        for encoder, level in ways:
            size = np.mean([len(encode_bilevel_tiff(p, width, dpi, "deflate", spacing, level=level, encoder=encoder))
                            for p in layers])
            seconds = best_of(args.repeats, lambda: [encode_bilevel_tiff(p, width, dpi, "deflate", spacing,
                                                                         level=level, encoder=encoder) for p in layers],
                              time.process_time if args.cpu else time.perf_counter)
            print(f"  {kind:8s} {encoder:7s} level {level}: {size / 1024:6.1f} KB  "
                  f"{seconds / len(layers) * 1e3:6.3f} ms a file{' (CPU)' if args.cpu else ''}, "
                  f"{size * len(layers) / 1e6:6.2f} MB and {seconds:.3f} s in all {len(layers)}")
    solid = kinds["solid"][len(kinds["solid"]) // 2]
    pair = {"tifffile.imwrite": lambda: by_tifffile(solid, width, dpi, spacing),
            "recalled layout": lambda: encode_bilevel_tiff(solid, width, dpi, "deflate", spacing)}
    times: dict[str, list[float]] = {name: [] for name in pair}
    for _ in range(5):
        for name, work in pair.items():
            times[name].append(best_of(40, work))
    for name, values in times.items():
        print(f"  one solid layer, level 1, {name}: {np.median(values) * 1e3:.3f} ms (median of 5, best of 40 each)")
    if args.codecs:
        labels = job_labels(args.labels, manifest, manifest["layers"][::args.every]) if args.labels else []
        best_layer(codec_survey(kinds, width, labels), args.sl1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
