"""A print job and where it comes from: a verified stack becomes a :class:`JobSpec` and a layer source.

Channel 0 of a layer is its solid mask, channels 1.. its droplet masks, each bit-packed by rows
(docs/protocol.md section 3), each mask on the printer channel its material names in the manifest
(:func:`heoslice.stack.mask_channels`). The job id is the CRC-32 of the stack's manifest.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from heoslice.errors import HeosliceError, InputError, StackChangedError
from heoslice.printing import protocol as P
from heoslice.stack import mask_channels, widest_masks

LayerSource = Callable[[int], Sequence[bytes]]


@dataclass(frozen=True)
class JobSpec:
    """A print job: ``layer_count`` layers of ``channels`` bit-packed masks of ``width`` x ``height`` pixels;
    ``names``: what each channel carries ('solid', then the droplet masks' materials), when known;
    ``stored_bytes``: bytes each layer's files take in the stack (its masks compressed), when known, which a
    sampled dry run scales its figures by, and ``blank``: whether each layer has no solid pixel (every channel
    zero), when known, which it sizes exactly (:func:`heoslice.printing.stream.plan_transfer`)."""

    job_id: int
    layer_count: int
    channels: int
    width: int
    height: int
    names: tuple[str, ...] = ()
    stored_bytes: tuple[int, ...] = field(default=(), repr=False, compare=False)
    blank: tuple[bool, ...] = field(default=(), repr=False, compare=False)

    @property
    def channel_bytes(self) -> int:
        """Bytes of one channel of one layer: rows packed MSB first, each padded to whole bytes."""
        return self.height * ((self.width + 7) // 8)


def pack_mask(mask: np.ndarray) -> bytes:
    """Channel payload of a (height, width) bool mask: ``np.packbits`` along rows (MSB first, rows padded)."""
    return np.packbits(np.asarray(mask, dtype=bool), axis=1).tobytes()


def stack_job(directory: Path, progress: Callable[[int, int], None] | None = None) -> tuple[JobSpec, LayerSource]:
    """Verify a stack (VerifyError if it fails), refuse one that cannot print (InputError:
    :func:`heoslice.stack.check_printable`) and return its job and layer source.

    Channel 0 is the solid mask; each droplet mask of a layer entry's ``"channels"`` list goes on the printer
    channel :func:`mask_channels` gives it, and channels no mask names (below the highest, or of a layer
    with fewer masks) carry empty masks. Each layer is checked against its sha256 again when it is read for
    sending; a mismatch or a missing file raises StackChangedError (exit 19). ``progress(done, total)`` follows
    the verification. A layer's masks are read as packed rows (:mod:`heoslice.stack.packed`), which are the
    channel payloads as they are.
    """
    from heoslice.stack import check_printable, load_verified
    from heoslice.stack.packed import layer_bits

    directory = Path(directory)
    manifest = load_verified(directory, progress, layer_map)
    layers = manifest["layers"]
    if not layers:
        raise InputError(f"{directory}: the stack has no layers")
    check_printable(manifest, directory)
    width, height = manifest["image"]["width"], manifest["image"]["height"]
    widest = widest_masks(manifest)
    targets = mask_channels(manifest, directory)
    channels = 1 + max(targets, default=0)
    names = ["solid", *(["unused"] * (channels - 1))]
    for channel, target in zip(widest, targets):
        names[target] = str(channel.get("material", f"channel {target}"))
    job_id = P.crc32(json.dumps(manifest, sort_keys=True).encode()) or 1
    job = JobSpec(job_id, len(layers), channels, width, height, tuple(names), stored_layer_bytes(directory, layers),
                  tuple(entry["solid_pixels"] == 0 for entry in layers))

    def read(index: int) -> list[bytes]:
        solid, masks = layer_bits(directory, manifest, index)
        out = [solid.rows.tobytes()] + [bytes(job.channel_bytes)] * (channels - 1)
        for mask, target in zip(masks, targets):
            out[target] = mask.rows.tobytes()
        return out

    def get_layer(index: int) -> list[bytes]:
        """Layer ``index``, read and checked again now: a file that changed since verification stops the print."""
        try:
            return read(index)
        except (HeosliceError, OSError, ValueError) as err:
            raise StackChangedError(f"{directory}: the stack changed while it was being printed (layer {index}: "
                                    f"{err}); ABORT sent; verify the stack and print it again") from None

    return job, get_layer


def stored_layer_bytes(directory: Path, layers: list[dict]) -> tuple[int, ...]:
    """Bytes of each layer's files (its own and its droplet masks') in a verified stack, from the file system;
    StackChangedError when one went missing since it was verified."""
    try:
        return tuple(sum((directory / name).stat().st_size
                         for name in [entry["file"], *(channel["file"] for channel in entry.get("channels") or [])])
                     for entry in layers)
    except OSError as err:
        raise StackChangedError(f"{directory}: the stack changed after it was verified ({err.filename}: "
                                f"{err.strerror}); verify it again") from None


#: Most layers one worker task carries (see :func:`layer_map`).
BATCH_LAYERS = 64


def layer_map(function: Callable, layers: Sequence[int], workers: int | None = None) -> Iterator:
    """``function(layer)`` for each of ``layers`` in order, over the cores (pipeline.parallel.ordered_map) in runs
    of up to BATCH_LAYERS layers: one small task a layer made the pipe's round trips, not the work, the cost of
    a dry run of tens of thousands of small layers."""
    from heoslice.pipeline.parallel import ordered_map

    return ordered_map(function, layers, workers, most_batched=BATCH_LAYERS)


def job_summary(job: JobSpec) -> str:
    """One line describing a job."""
    shown = f" ({', '.join(job.names)})" if job.names else ""
    return (f"{job.layer_count} layers, {job.channels} channel(s){shown} of {job.width} x {job.height} px "
            f"({job.channel_bytes} bytes each), job id {job.job_id:08x}")
