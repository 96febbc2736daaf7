"""The data stream of a job: JOB_BEGIN, then per layer LAYER_BEGIN, its chunks, LAYER_END, EXECUTE; JOB_END.

:func:`next_chunk` picks DATA (raw, address implicit) or an encoded CHUNK for each piece of a layer
(docs/protocol.md section 4); :func:`job_messages` yields the messages with chunk sizes chosen by
the caller at the moment each chunk is made, so they follow the link's error rate.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

from heoslice.errors import InputError
from heoslice.printing import protocol as P
from heoslice.printing.job import JobSpec, LayerSource, layer_map

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


def plan_transfer(job: JobSpec, get_layer: LayerSource, *, baud: int = 115200, max_payload: int = 1024,
                  encodings: int = P.ALL_ENCODINGS, from_layer: int = 0, workers: int | None = None,
                  progress: Callable[[int, int], None] | None = None) -> dict:
    """Encode every frame of the job without a port: frames, wire bytes and the time at ``baud`` (8N1), s.
    The layers are read and encoded in ``workers`` processes (:func:`heoslice.printing.job.layer_map`; default
    one per core); ``progress(done, total)`` follows them."""
    check_from_layer(job, from_layer)

    def layer_plan(index: int) -> tuple[int, int, int]:
        frames, wire, raw = 3, 3 * P.wire_size(13), 0
        for number, data in enumerate(get_layer(index)):
            raw += len(data)
            offset = 0
            while offset < len(data):
                message, span = next_chunk(index, number, data, offset, max_payload, encodings)
                frames += 1
                wire += P.wire_size(len(P.pack_message(message)[1]))
                offset += span
        return frames, wire, raw

    frames = wire = raw = 0
    indices = range(from_layer, job.layer_count)
    for done, (layer_frames, layer_wire, layer_raw) in enumerate(layer_map(layer_plan, indices, workers), 1):
        frames, wire, raw = frames + layer_frames, wire + layer_wire, raw + layer_raw
        if progress is not None:
            progress(done, len(indices))
    return {"layers": job.layer_count - from_layer, "channels": job.channels, "raw_bytes": raw,
            "frames": frames, "wire_bytes": wire, "seconds_at_baud": wire * 10.0 / baud}


def check_from_layer(job: JobSpec, from_layer: int) -> None:
    """--from-layer must name a layer of the stack (the same rule for a print and a dry run)."""
    if not 0 <= from_layer < job.layer_count:
        raise InputError(f"--from-layer {from_layer} is outside the stack's layers 0..{job.layer_count - 1}")
