"""A print job and where it comes from: a verified stack becomes a :class:`JobSpec` and a layer source.

Channel 0 of a layer is its solid mask, channels 1.. its droplet masks, each bit-packed by rows
(docs/protocol.md section 3), each mask on the printer channel its material names in the manifest
(:func:`heoslice.stack.mask_channels`). The job id is the CRC-32 of the stack's manifest.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Collection, Iterator, Sequence
from dataclasses import dataclass, field, replace
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
    dpi: tuple[float, float] | None = None  # the stack's (x, y) resolution, which the printer's must be

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
    job, get_layer, _ = verified_job(directory, progress)
    return job, get_layer


#: ``early(job)``: the layers whose channels a reader wants while the stack is verified, and what to make of
#: them, ``work(index, channels)`` (small: it is sent back from the worker); ``job`` is made from the manifest
#: before it is verified (without ``stored_bytes``).
EarlyWork = Callable[[JobSpec], tuple[Collection[int], Callable[[int, list[bytes]], object]]]


def verified_job(directory: Path, progress: Callable[[int, int], None] | None = None,
                 early: EarlyWork | None = None) -> tuple[JobSpec, LayerSource, dict[int, object]]:
    """:func:`stack_job`'s job and layer source, and what ``early`` (:data:`EarlyWork`) made of the channels of
    the layers it named, from the same reading of each as its verification (a dry run sizes its sample so,
    without reading those layers again). Refuses exactly as :func:`stack_job` does, whatever ``early`` is."""
    from heoslice.stack import check_printable, verify_stack
    from heoslice.stack.packed import layer_bits
    from heoslice.stack.verify import refusal

    directory = Path(directory)
    made = {}  # the manifest's job and mask channels, made once (the report's manifest is the one given here)

    def also(manifest: dict):
        try:
            job, targets = made["job"] = _job_of(manifest, directory)
        except (HeosliceError, KeyError, TypeError, ValueError):  # not a manifest that verifies: no early work
            return None
        layers, work = early(job)
        return layers, lambda index, bits: work(index, channel_payloads(job, targets, bits[0], bits[1:]))

    report = verify_stack(directory, layer_map=layer_map, progress=progress, also=also if early else None)
    if not report.ok:
        raise refusal(directory, report.problems)
    manifest = report.manifest
    if not manifest["layers"]:
        raise InputError(f"{directory}: the stack has no layers")
    check_printable(manifest, directory)
    job, targets = made.get("job") or _job_of(manifest, directory)
    job = replace(job, stored_bytes=stored_layer_bytes(directory, manifest["layers"]))

    def read(index: int) -> list[bytes]:
        solid, masks = layer_bits(directory, manifest, index)
        return channel_payloads(job, targets, solid, masks)

    def get_layer(index: int) -> list[bytes]:
        """Layer ``index``, read and checked again now: a file that changed since verification stops the print."""
        try:
            return read(index)
        except (HeosliceError, OSError, ValueError) as err:
            named = str(err) if str(err).startswith(f"layer {index}:") else f"layer {index}: {err}"
            raise StackChangedError(f"{directory}: the stack changed while it was being printed ({named}); ABORT "
                                    "sent; verify the stack and print it again") from None

    return job, get_layer, report.also


def _job_of(manifest: dict, directory: Path) -> tuple[JobSpec, tuple[int, ...]]:
    """The :class:`JobSpec` of a stack's manifest (without ``stored_bytes``) and each droplet mask's printer
    channel (:func:`mask_channels`)."""
    layers = manifest["layers"]
    widest = widest_masks(manifest)
    targets = mask_channels(manifest, directory)
    channels = 1 + max(targets, default=0)
    names = ["solid", *(["unused"] * (channels - 1))]
    for channel, target in zip(widest, targets):
        names[target] = str(channel.get("material", f"channel {target}"))
    job_id = P.crc32(json.dumps(manifest, sort_keys=True).encode()) or 1
    job = JobSpec(job_id, len(layers), channels, manifest["image"]["width"], manifest["image"]["height"],
                  tuple(names), (), tuple(entry["solid_pixels"] == 0 for entry in layers),
                  (float(manifest["dpi"][0]), float(manifest["dpi"][1])))
    return job, targets


#: How far (a share of the printer's) a stack's dpi may be from the printer's: the manifest's dpi is the slice's
#: --dpi, exact; a printer reports its resolution as a float (HELLO_ACK dpi_x, dpi_y; 0: not reported, not checked).
DPI_SLACK = 1e-3


def misfit(job: JobSpec, ack: P.HelloAck) -> str | None:
    """Why ``job`` cannot print on the printer a HELLO_ACK describes (more channels or pixels than it has, or a
    resolution other than its own: the part would come out at another size), or None when it fits."""
    if job.channels > ack.channels or job.width > ack.max_width or job.height > ack.max_height:
        return (f"the job ({job.channels} channel(s), {job.width} x {job.height} px) does not fit the printer "
                f"({ack.channels} channel(s), at most {ack.max_width} x {ack.max_height} px)")
    if job.dpi is not None and min(ack.dpi_x, ack.dpi_y) > 0 and (
            abs(job.dpi[0] - ack.dpi_x) > DPI_SLACK * ack.dpi_x or abs(job.dpi[1] - ack.dpi_y) > DPI_SLACK * ack.dpi_y):
        return (f"the stack is at {job.dpi[0]:g} x {job.dpi[1]:g} dpi, the printer prints at {ack.dpi_x:g} x "
                f"{ack.dpi_y:g} dpi (the part would come out at another size); slice it again with --dpi "
                f"{ack.dpi_x:g}x{ack.dpi_y:g}")
    return None


def channel_payloads(job: JobSpec, targets: Sequence[int], solid, masks: Sequence) -> list[bytes]:
    """A layer's channel payloads from its files' packed rows (:class:`heoslice.stack.packed.Bits`): the solid
    pixels on channel 0, each droplet mask on its printer channel ``targets`` gives, empty masks elsewhere."""
    out = [solid.rows.tobytes()] + [bytes(job.channel_bytes)] * (job.channels - 1)
    for mask, target in zip(masks, targets):
        out[target] = mask.rows.tobytes()
    return out


def stored_layer_bytes(directory: Path, layers: list[dict]) -> tuple[int, ...]:
    """Bytes of each layer's files (its own and its droplet masks') in a verified stack, from the file system;
    StackChangedError when one went missing since it was verified."""
    folder = str(directory)
    try:
        return tuple(sum(os.stat(os.path.join(folder, name)).st_size
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
