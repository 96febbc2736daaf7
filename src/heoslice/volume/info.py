"""What a volume holds, for ``heoslice info``: shape, voxel size, orientation, physical extent, and per label
its name (where the file gives one), voxel count and volume."""

from __future__ import annotations

import numpy as np

from heoslice.volume.model import Volume


def orientation_codes(volume: Volume) -> str:
    """Where the voxel axes i, j, k point, in anatomical letters (e.g. 'RAS', 'LPS'; nibabel's aff2axcodes on
    the RAS affine, so the same letters whatever space the file is stored in)."""
    from nibabel.orientations import aff2axcodes

    return "".join(code or "?" for code in aff2axcodes(volume.ras_affine()))


def extent_mm(volume: Volume) -> np.ndarray:
    """(2, 3) float, mm: the low and high corner, in the volume's own space, of the box its voxels fill (each
    voxel reaching half a voxel beyond its centre)."""
    shape = np.array(volume.shape, dtype=np.float64)
    corners = np.array([[a, b, c] for a in (-0.5, shape[0] - 0.5) for b in (-0.5, shape[1] - 0.5)
                        for c in (-0.5, shape[2] - 0.5)])
    points = corners @ volume.affine[:3, :3].T + volume.affine[:3, 3]
    return np.stack([points.min(axis=0), points.max(axis=0)])


def label_counts(volume: Volume) -> list[int]:
    """Voxels of each of ``volume.labels``, in order."""
    counts = []
    for layer in range(volume.layer_count):
        values, number = np.unique(volume.layer(layer), return_counts=True)
        counts.append(dict(zip(values.tolist(), number.tolist())))
    return [int(counts[label.layer].get(label.value, 0)) for label in volume.labels]


def volume_info(volume: Volume) -> dict:
    """The JSON-ready summary ``info`` prints for a volume."""
    low, high = extent_mm(volume)
    voxel = volume.voxel_volume_mm3
    summary = {
        "file": str(volume.source),
        "kind": volume.kind,
        "shape": list(volume.shape),
        "layers": volume.layer_count,
        "voxel_size_mm": [float(v) for v in volume.voxel_size_mm],
        "space": volume.space,
        "orientation": orientation_codes(volume),
        "extent_mm": [low.tolist(), high.tolist()],
        "size_mm": (high - low).tolist(),
        "warnings": list(volume.warnings),
    }
    if volume.kind == "labels":
        summary["labels"] = [{"value": label.value, "name": label.name, "layer": label.layer, "voxels": count,
                              "volume_mm3": count * voxel}
                             for label, count in zip(volume.labels, label_counts(volume))]
    else:
        data = volume.data
        summary["values"] = {"min": float(data.min()), "max": float(data.max()), "mean": float(data.mean())}
    return summary


def info_lines(summary: dict) -> list[str]:
    """The text lines of a volume's summary (:func:`volume_info`)."""
    low, high = summary["extent_mm"]
    size = summary["size_mm"]
    lines = [
        f"file:               {summary['file']}",
        f"kind:               {'label map' if summary['kind'] == 'labels' else 'intensity volume'}"
        + (f" ({summary['layers']} layers: overlapping structures)" if summary["layers"] > 1 else ""),
        f"shape (voxels):     {' x '.join(map(str, summary['shape']))}",
        f"voxel size (mm):    {' x '.join(f'{v:.4g}' for v in summary['voxel_size_mm'])}",
        f"orientation:        {summary['orientation']} (where voxel axes i, j, k point; stored in {summary['space']})",
        f"extent (mm, {summary['space']}): x {low[0]:.4g} .. {high[0]:.4g}, y {low[1]:.4g} .. {high[1]:.4g}, "
        f"z {low[2]:.4g} .. {high[2]:.4g} ({size[0]:.4g} x {size[1]:.4g} x {size[2]:.4g} mm)",
    ]
    if "values" in summary:
        values = summary["values"]
        lines.append(f"values:             {values['min']:.6g} .. {values['max']:.6g} (mean {values['mean']:.6g})")
    for label in summary.get("labels", []):
        name = label["name"] or "(no name in the file)"
        lines.append(f"label {label['value']:>5}:        {name}: {label['voxels']} voxels, "
                     f"{label['volume_mm3']:.6g} mm^3"
                     + (f" (layer {label['layer']})" if summary["layers"] > 1 else ""))
    lines += [f"warning:            {text}" for text in summary["warnings"]]
    return lines


def printed_voxel_volume_mm3(volume: Volume, records: list[dict]) -> float:
    """The voxel volume (mm^3) of the labels a stack's manifest lists as printed (``labels``: value and layer
    each): what ``verify --mesh VOLUME`` compares the stack's volume with. A listed label the volume does
    not hold counts 0 voxels."""
    counts = dict(zip(((label.layer, label.value) for label in volume.labels), label_counts(volume)))
    voxels = sum(counts.get((int(record.get("layer", 0)), int(record["value"])), 0) for record in records)
    return voxels * volume.voxel_volume_mm3
