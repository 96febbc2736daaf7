"""The data stream of a job: JOB_BEGIN, then per layer LAYER_BEGIN, its chunks, LAYER_END, EXECUTE; JOB_END.

:func:`next_chunk` picks DATA (raw, address implicit) or an encoded CHUNK for each piece of a layer
(docs/protocol.md section 4); :func:`job_messages` yields the messages with chunk sizes chosen by
the caller at the moment each chunk is made, so they follow the link's error rate; :func:`plan_transfer`
sizes the stream without a port (a dry run), from every layer or from an even sample of them, and
:func:`dry_run` sizes it from the verification's reading of the layers it encodes.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path

import numpy as np

from heoslice.errors import InputError
from heoslice.printing import protocol as P
from heoslice.printing.job import JobSpec, LayerSource, layer_map, verified_job

#: Bytes a CHUNK adds to the frame before its data (a DATA adds none).
CHUNK_HEADER = 12


def next_chunk(layer: int, channel: int, data: bytes, offset: int, payload: int,
               encodings: int) -> tuple[P.Data | P.Chunk, int]:
    """The data message carrying ``data`` from ``offset`` in a frame payload of at most ``payload`` bytes.

    A DATA (raw, address implicit) of up to ``payload`` bytes, unless an encoded CHUNK carries
    more raw bytes, or the same in fewer payload bytes; returns (message, raw bytes carried).
    """
    remaining = len(data) - offset
    raw_span = min(remaining, payload)
    budget = payload - CHUNK_HEADER
    span = min(remaining, 0xFFFF, budget * 16)
    if encodings != 1 << P.ENC_RAW and budget > 0:
        for _ in range(6):
            if span < raw_span or span <= 0:
                break
            code, encoded = P.encode_chunk(data[offset:offset + span], encodings)
            if len(encoded) <= budget:
                if span > raw_span or len(encoded) + CHUNK_HEADER < raw_span:
                    return P.Chunk(layer, channel, offset, code, span, encoded), span
                break
            span = int(span * budget / len(encoded) * 0.9)
    return P.Data(data[offset:offset + raw_span]), raw_span


def job_messages(job: JobSpec, get_layer: LayerSource, start: int, payload: Callable[[], int],
                 encodings: int, name: str = "") -> Iterator[tuple[P.Message, int, int]]:
    """(message, layer, raw bytes carried) of the data stream from layer ``start``.

    ``payload()`` is asked for the frame payload budget before each chunk is made; ``name`` (the
    stack's) goes with JOB_BEGIN, cut to ``JOB_NAME_LIMIT`` bytes on a character boundary.
    """
    encoded = name.encode("utf-8")[:P.JOB_NAME_LIMIT].decode("utf-8", "ignore").encode("utf-8")
    yield P.JobBegin(job.job_id, start, job.layer_count, job.channels, job.width, job.height, encoded), -1, 0
    for index in range(start, job.layer_count):
        channels = list(get_layer(index))
        if len(channels) != job.channels or any(len(c) != job.channel_bytes for c in channels):
            raise InputError(f"layer {index}: expected {job.channels} channel(s) of {job.channel_bytes} bytes")
        yield P.LayerBegin(index, job.channels, job.channel_bytes, P.crc32(b"".join(channels))), index, 0
        for number, data in enumerate(channels):
            offset = 0
            while offset < len(data):
                chunk, used = next_chunk(index, number, data, offset, payload(), encodings)
                yield chunk, index, used
                offset += used
        yield P.LayerEnd(index), index, 0
        yield P.Execute(index), index, 0
    yield P.JobEnd(job.job_id), job.layer_count - 1, 0


#: Layers a dry run encodes to estimate the transfer of a larger stack (:func:`plan_transfer`'s ``sample``);
#: the estimate's error against encoding every layer is measured in benchmarks/README.md.
SAMPLE_LAYERS = 32


def sample_layers(first: int, stop: int, count: int) -> list[int]:
    """``count`` layers of first..stop-1 spread evenly, the middle one of each of ``count`` equal runs; every
    layer when there are no more than ``count``. Deterministic: the same stack gives the same sample."""
    total = stop - first
    if total <= count:
        return list(range(first, stop))
    return [first + (2 * run + 1) * total // (2 * count) for run in range(count)]


def regression_total(values: Sequence[float], sampled: Sequence[float], every: Sequence[float]) -> float:
    """The sum over every layer of a figure known on a sample of them (``values``), by the regression estimator
    N ybar + b (X - N xbar) (Cochran, Sampling Techniques, 3rd ed., chapter 7): x is an auxiliary known for
    every layer (``every``; ``sampled`` its sampled layers' values), b the least-squares slope of the figure on x
    over the sample, 0 when x does not vary there (the estimate is then N ybar). Exact for a figure linear in x."""
    y, x, known = (np.asarray(a, dtype=float) for a in (values, sampled, every))
    spread = x - x.mean()
    slope = float(spread @ (y - y.mean()) / (spread @ spread)) if spread.any() else 0.0
    return len(known) * y.mean() + slope * (known.sum() - len(known) * x.mean())


def layer_figures(job: JobSpec, index: int, channels: Sequence[bytes], max_payload: int = 1024,
                  encodings: int = P.ALL_ENCODINGS) -> tuple[int, int, int]:
    """(frames, wire bytes, raw bytes) of layer ``index`` of ``job`` with these channel payloads: its chunks
    made as a print with a frame payload of ``max_payload`` makes them, and its framing messages."""
    framing = _framing(job)
    sized: list[tuple[bytes, tuple[int, int]]] = []  # a channel's bytes, its frames and wire bytes
    frames, wire, raw = 3, framing, 0
    for number, data in enumerate(channels):
        raw += len(data)
        # a channel equal to an earlier one (a droplet mask holding the whole layer) frames alike: the chunks
        # are cut from the bytes alone, and a frame's wire bytes follow its length alone
        figures = next((known for earlier, known in sized if earlier == data), None)
        if figures is None:
            figures = _channel_figures(index, number, data, max_payload, encodings)
            sized.append((data, figures))
        frames, wire = frames + figures[0], wire + figures[1]
    return frames, wire, raw


def _channel_figures(index: int, number: int, data: bytes, max_payload: int, encodings: int) -> tuple[int, int]:
    """(frames, wire bytes) of one channel's chunks."""
    frames = wire = offset = 0
    while offset < len(data):
        message, span = next_chunk(index, number, data, offset, max_payload, encodings)
        frames += 1
        wire += P.wire_size(len(P.pack_message(message)[1]))
        offset += span
    return frames, wire


def _framing(job: JobSpec) -> int:
    """Wire bytes of a layer's LAYER_BEGIN, LAYER_END and EXECUTE."""
    return sum(P.wire_size(len(P.pack_message(message)[1]))
               for message in (P.LayerBegin(0, job.channels, job.channel_bytes, 0), P.LayerEnd(0), P.Execute(0)))


def encoded_layers(job: JobSpec, from_layer: int = 0, sample: int | None = None) -> list[int]:
    """The layers :func:`plan_transfer` encodes: every one from ``from_layer`` when ``sample`` is None, else
    ``sample`` of those with solid pixels spread evenly (:func:`sample_layers`; all of them when there are no
    more) and the first blank one (``job.blank``)."""
    check_from_layer(job, from_layer)
    if sample is not None and sample < 1:
        raise ValueError(f"a dry run's sample is at least one layer, not {sample}")
    indices = range(from_layer, job.layer_count)
    if sample is None:
        return list(indices)
    blank = [index for index in indices if job.blank and job.blank[index]]
    filled = [index for index in indices if not (job.blank and job.blank[index])]
    return [filled[k] for k in sample_layers(0, len(filled), sample)] + blank[:1]


def plan_transfer(job: JobSpec, get_layer: LayerSource, *, baud: int = 115200, max_payload: int = 1024,
                  encodings: int = P.ALL_ENCODINGS, from_layer: int = 0, sample: int | None = None,
                  workers: int | None = None, progress: Callable[[int, int], None] | None = None,
                  planned: Mapping[int, tuple[int, int, int]] | None = None) -> dict:
    """Encode the frames of the job as a print would, without a port: frames, wire bytes and the time at
    ``baud`` (8N1), s. The layers are read and encoded in ``workers`` processes
    (:func:`heoslice.printing.job.layer_map`; default one per core); ``progress(done, total)`` follows them.
    ``planned`` holds the :func:`layer_figures` of layers encoded already (by the same ``max_payload`` and
    ``encodings``), which are not read again.

    Every layer is encoded when ``sample`` is None. Else one blank layer (``job.blank``) is encoded for all of
    them (every blank layer encodes alike, so they are counted exactly), the layers with solid pixels are all
    encoded when there are no more than ``sample``, and otherwise ``sample`` of them spread evenly
    (:func:`sample_layers`), their frames and wire bytes then estimated by :func:`regression_total` on the bytes
    each layer's files take in the stack (``job.stored_bytes``: the same masks, compressed, so a layer's encoded
    size follows them; without them, by the sample's mean per layer), at least the frames (framing and one data
    frame a channel) and framing bytes every such layer sends. The raw bytes are exact either way; the result says whether the rest is estimated (``estimated``) and from
    how many layers (``layers_encoded``)."""
    chosen = encoded_layers(job, from_layer, sample)
    framing = _framing(job)
    indices = range(from_layer, job.layer_count)
    if sample is None:  # every layer encoded
        blank, filled, estimated = [], list(indices), False
    else:  # one blank layer encoded for all of them (they encode alike), the others sampled when there are more
        blank = [index for index in indices if job.blank and job.blank[index]]
        filled = [index for index in indices if not (job.blank and job.blank[index])]
        estimated = len(filled) > sample
    planned = {index: planned[index] for index in chosen if planned and index in planned}
    missing = [index for index in chosen if index not in planned]
    figures = layer_map(lambda index: layer_figures(job, index, get_layer(index), max_payload, encodings), missing,
                        workers)
    for done, (index, layer) in enumerate(zip(missing, figures), len(chosen) - len(missing) + 1):
        planned[index] = layer
        if progress is not None:
            progress(done, len(chosen))
    blank_figures = planned[blank[0]] if blank else (0, 0, 0)
    totals = [sum(planned[index][k] for index in filled if index in planned) + len(blank) * blank_figures[k]
              for k in range(3)]
    if estimated:
        stored = {index: job.stored_bytes[index] if job.stored_bytes else 0 for index in filled}
        sampled = chosen[:len(chosen) - len(blank[:1])]
        for k, least in ((0, (3 + job.channels) * len(filled)), (1, framing * len(filled))):  # at least framing
            estimate = regression_total([planned[index][k] for index in sampled], [stored[index] for index in sampled],
                                        list(stored.values()))
            totals[k] = max(round(estimate), least) + len(blank) * blank_figures[k]
        totals[2] = len(indices) * job.channels * job.channel_bytes
    layers = len(indices)
    return {"layers": layers, "channels": job.channels, "raw_bytes": totals[2], "frames": totals[0],
            "wire_bytes": totals[1], "seconds_at_baud": totals[1] * 10.0 / baud, "estimated": estimated,
            "layers_encoded": len(chosen)}


def dry_run(directory: Path, *, max_payload: int = 1024, baud: int = 115200, from_layer: int = 0,
            sample: int | None = SAMPLE_LAYERS, verifying: Callable[[int, int], None] | None = None,
            sizing: Callable[[int, int], None] | None = None) -> tuple[JobSpec, dict]:
    """A print's verification of a stack (:func:`heoslice.printing.job.stack_job`: it refuses what a print
    refuses) and :func:`plan_transfer`'s figures, with the layers it encodes (:func:`encoded_layers`)
    encoded from their reading by the verification, in its workers: (the job, the figures).
    ``verifying(done, total)`` follows the verification, ``sizing`` the encoding of any layer left."""
    def early(job: JobSpec):
        try:
            layers = encoded_layers(job, from_layer, sample)
        except (InputError, ValueError):  # refused after the verification, as a print refuses it
            layers = []
        return layers, lambda index, channels: layer_figures(job, index, channels, max_payload)

    job, get_layer, planned = verified_job(directory, verifying, early)
    return job, plan_transfer(job, get_layer, baud=baud, max_payload=max_payload, from_layer=from_layer,
                              sample=sample, progress=sizing, planned=planned)


def check_from_layer(job: JobSpec, from_layer: int) -> None:
    """--from-layer must name a layer of the stack (the same rule for a print and a dry run)."""
    if not 0 <= from_layer < job.layer_count:
        raise InputError(f"--from-layer {from_layer} is outside the stack's layers 0..{job.layer_count - 1}")
