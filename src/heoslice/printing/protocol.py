"""The heoslice printer wire protocol, version 3: pure codecs, no I/O.

Specified in ``docs/protocol.md``. A frame is ``COBS(header + payload + CRC-32) + 0x00``;
the header is ``<BBHHHH`` (version, type, session, seq, ack, payload length), all
integers little-endian, and the CRC is zlib's CRC-32 of header and payload. Messages
are small frozen dataclasses; :func:`pack_message` / :func:`unpack_message` map them
to and from payload bytes. Every decoder here raises only :class:`ProtocolError`.
"""

from __future__ import annotations

import functools
import struct
import zlib
from dataclasses import dataclass, fields
from typing import ClassVar

import numpy as np

from heoslice.deflate import deflater
from heoslice.errors import ProtocolError

PROTOCOL_VERSION = 3
HEADER = struct.Struct("<BBHHHH")
CRC = struct.Struct("<I")
#: Largest payload any peer may send or accept, bytes.
MAX_PAYLOAD_LIMIT = 4096
#: Bytes of header + CRC around a payload (before COBS and the delimiter).
FRAME_OVERHEAD = HEADER.size + CRC.size
SEQ_MODULUS = 1 << 16
#: Wire bytes a frame adds to its payload when header + payload + CRC is under 254 bytes: header, CRC,
#: the COBS code byte and the delimiter (one more COBS byte per further 254).
WIRE_OVERHEAD = FRAME_OVERHEAD + 2

# Protocol extensions offered in HELLO.features and enabled in HELLO_ACK.features (bit masks).
#: Selective acknowledgement: the controller keeps data frames that arrive after a gap and reports
#: them in ACK/NAK ``held``; the host skips them when it goes back (docs/protocol.md section 5).
FEATURE_SACK = 1 << 0
ALL_FEATURES = FEATURE_SACK
#: Frames after the next expected one that ``held`` can report (bit i: seq expected + 1 + i).
SACK_SPAN = 64

# Chunk encodings: the code sent in CHUNK.encoding; the bit ``1 << code`` in HELLO masks.
ENC_RAW = 0
ENC_PACKBITS = 1
ENC_ZLIB = 2
ENCODING_NAMES = {ENC_RAW: "raw", ENC_PACKBITS: "packbits", ENC_ZLIB: "zlib"}
ALL_ENCODINGS = (1 << ENC_RAW) | (1 << ENC_PACKBITS) | (1 << ENC_ZLIB)

# Controller states (STATUS.state, HELLO_ACK.state).
STATE_IDLE = 0
STATE_RECEIVING = 1
STATE_PAUSED = 2
STATE_DONE = 3
STATE_ERROR = 4
STATE_ABORTED = 5
STATE_NAMES = {STATE_IDLE: "idle", STATE_RECEIVING: "receiving", STATE_PAUSED: "paused",
               STATE_DONE: "done", STATE_ERROR: "error", STATE_ABORTED: "aborted"}

# Controller error codes (STATUS.error).
ERR_NONE = 0
ERR_LAYER_CRC = 1
ERR_OUT_OF_ORDER = 2
ERR_HARDWARE = 3
ERR_BAD_JOB = 4
ERROR_NAMES = {ERR_NONE: "none", ERR_LAYER_CRC: "layer CRC mismatch",
               ERR_OUT_OF_ORDER: "layer out of order", ERR_HARDWARE: "hardware fault",
               ERR_BAD_JOB: "job does not fit this printer"}

# HELLO_ACK flags.
#: Another host's run holds the controller (a live job of another host id): no session was opened.
HELLO_BUSY = 1 << 0

# NAK reasons.
NAK_OUT_OF_ORDER = 1
NAK_NO_CREDIT = 2
NAK_BAD_FRAME = 3


def crc32(data: bytes) -> int:
    """CRC-32 exactly as zlib computes it (check value of b'123456789' is 0xCBF43926)."""
    return zlib.crc32(data) & 0xFFFFFFFF


def cobs_encode(data: bytes) -> bytes:
    """COBS-encode ``data`` (the result holds no zero byte; the caller appends the 0x00 delimiter).

    Written here rather than imported: the one PyPI package (``cobs``) ships only a C
    source distribution, and the codec is a few lines over ``bytes.split``.
    """
    out = bytearray()
    blocks = data.split(b"\x00")
    last = len(blocks) - 1
    for number, block in enumerate(blocks):
        long_block = False
        while len(block) >= 254:
            out.append(0xFF)
            out += block[:254]
            block = block[254:]
            long_block = True
        if number == last and long_block and not block:
            break
        out.append(len(block) + 1)
        out += block
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    """Invert :func:`cobs_encode`; raise ProtocolError on a zero byte or a truncated block."""
    if not data:
        raise ProtocolError("empty COBS block")
    out = bytearray()
    position, size = 0, len(data)
    while position < size:
        code = data[position]
        if code == 0:
            raise ProtocolError("zero byte inside a COBS frame")
        end = position + code
        if end > size:
            raise ProtocolError("truncated COBS block")
        block = data[position + 1:end]
        if 0 in block:
            raise ProtocolError("zero byte inside a COBS frame")
        out += block
        position = end
        if code < 0xFF and position < size:
            out.append(0)
    return bytes(out)


@dataclass(frozen=True)
class Frame:
    """One decoded frame: header fields and the raw payload."""

    type: int
    session: int
    seq: int
    ack: int
    payload: bytes = b""
    version: int = PROTOCOL_VERSION


def encode_frame(frame: Frame) -> bytes:
    """Wire bytes of ``frame``: COBS(header + payload + CRC-32) followed by the 0x00 delimiter."""
    if len(frame.payload) > MAX_PAYLOAD_LIMIT:
        raise ProtocolError(f"payload of {len(frame.payload)} bytes exceeds {MAX_PAYLOAD_LIMIT}")
    body = HEADER.pack(frame.version, frame.type, frame.session, frame.seq, frame.ack,
                       len(frame.payload)) + frame.payload
    return cobs_encode(body + CRC.pack(crc32(body))) + b"\x00"


def decode_frame(data: bytes) -> Frame:
    """Decode one frame's COBS bytes (without the delimiter); check length and CRC."""
    body = cobs_decode(data)
    if len(body) < FRAME_OVERHEAD:
        raise ProtocolError(f"frame of {len(body)} bytes is shorter than {FRAME_OVERHEAD}")
    (expected,) = CRC.unpack_from(body, len(body) - CRC.size)
    if crc32(body[:-CRC.size]) != expected:
        raise ProtocolError("frame CRC mismatch")
    version, kind, session, seq, ack, length = HEADER.unpack_from(body)
    if length != len(body) - FRAME_OVERHEAD:
        raise ProtocolError(f"header says {length} payload bytes, frame holds {len(body) - FRAME_OVERHEAD}")
    return Frame(kind, session, seq, ack, bytes(body[HEADER.size:-CRC.size]), version)


def wire_size(payload_bytes: int) -> int:
    """Upper bound of a frame's wire bytes for a payload of ``payload_bytes`` (COBS worst case + delimiter)."""
    body = payload_bytes + FRAME_OVERHEAD
    return body + body // 254 + 2


class FrameSplitter:
    """Cut a byte stream at 0x00 delimiters into frames; a stateful accumulator, so a class.

    :meth:`feed` returns decoded :class:`Frame` objects and, for each segment that fails
    to decode, the :class:`ProtocolError` (returned, not raised, so a caller can count
    errors and carry on). Segments longer than ``max_segment`` bytes are discarded.
    """

    def __init__(self, max_segment: int = wire_size(MAX_PAYLOAD_LIMIT)):
        self._buffer = bytearray()
        self._max = max_segment
        self._overflow = False

    def feed(self, data: bytes) -> list[Frame | ProtocolError]:
        """Add received bytes; return the frames (or errors) completed by them, in order."""
        out: list[Frame | ProtocolError] = []
        start = 0
        while True:
            end = data.find(b"\x00", start)
            if end < 0:
                break
            segment = bytes(self._buffer) + data[start:end]
            overflow = self._overflow or len(segment) > self._max
            self._buffer.clear()
            self._overflow = False
            start = end + 1
            if overflow:
                out.append(ProtocolError("over-long frame discarded"))
            elif segment:
                try:
                    out.append(decode_frame(segment))
                except ProtocolError as err:
                    out.append(err)
        rest = data[start:]
        if self._overflow or len(self._buffer) + len(rest) > self._max:
            self._overflow = True
            self._buffer.clear()
        else:
            self._buffer += rest
        return out


# --- messages -------------------------------------------------------------------------


@dataclass(frozen=True)
class Hello:
    """Host -> controller: open a session (header.session is the new session id)."""

    TYPE: ClassVar[int] = 0x01
    FORMAT: ClassVar[str] = "<BHBBI"
    version: int
    max_payload: int
    encodings: int
    features: int = 0
    host_id: int = 0  # the print run saying HELLO: random, non-zero, the same across its reconnects


@dataclass(frozen=True)
class HelloAck:
    """Controller -> host: capabilities and the state a resuming host needs."""

    TYPE: ClassVar[int] = 0x02
    FORMAT: ClassVar[str] = "<BIIHHBBIIffIIiiIBBB"
    version: int
    boot_id: int
    rx_buffer: int
    window: int
    max_payload: int
    encodings: int
    channels: int
    max_width: int
    max_height: int
    dpi_x: float
    dpi_y: float
    job_id: int
    run_id: int  # host id of the run that began or last continued the job (0: none)
    last_completed: int
    last_queued: int
    layer_count: int
    state: int
    features: int = 0
    flags: int = 0  # bit 0 HELLO_BUSY: another host holds the controller, no session was opened
    job_name: bytes = b""  # the job's name as JOB_BEGIN gave it (UTF-8), the rest of the payload
    TAIL: ClassVar[str] = "job_name"


@dataclass(frozen=True)
class JobBegin:
    """Start (or, with the active job's id, continue) a job of ``layer_count`` layers from ``first_layer``."""

    TYPE: ClassVar[int] = 0x10
    FORMAT: ClassVar[str] = "<IIIBII"
    job_id: int
    first_layer: int
    layer_count: int
    channels: int
    width: int
    height: int
    name: bytes = b""  # UTF-8, at most JOB_NAME_LIMIT bytes (the stack's name), the rest of the payload
    TAIL: ClassVar[str] = "name"


@dataclass(frozen=True)
class LayerBegin:
    """A layer's header: ``channels`` payloads of ``size`` raw bytes each, CRC-32 of their concatenation."""

    TYPE: ClassVar[int] = 0x11
    FORMAT: ClassVar[str] = "<IBII"
    layer: int
    channels: int
    size: int
    crc: int


@dataclass(frozen=True)
class Chunk:
    """``raw_len`` bytes of (layer, channel) at ``offset``, carried in ``encoding``; idempotent by address."""

    TYPE: ClassVar[int] = 0x12
    FORMAT: ClassVar[str] = "<IBIBH"
    layer: int
    channel: int
    offset: int
    encoding: int
    raw_len: int
    data: bytes = b""
    TAIL: ClassVar[str] = "data"


@dataclass(frozen=True)
class Data:
    """Raw layer bytes written at the layer's write cursor: the compact, address-implicit CHUNK.

    LAYER_BEGIN sets the cursor to 0, each CHUNK to the end of what it wrote, each DATA
    advances it by its length; the layer's channels are concatenated. Data frames are
    applied strictly in sequence order, so a DATA's (layer, channel, offset) is fixed by its
    place in the stream and a retransmission writes the same bytes at the same place.
    """

    TYPE: ClassVar[int] = 0x16
    FORMAT: ClassVar[str] = "<"
    data: bytes = b""
    TAIL: ClassVar[str] = "data"


@dataclass(frozen=True)
class LayerEnd:
    """All chunks of ``layer`` sent; the controller checks the layer CRC."""

    TYPE: ClassVar[int] = 0x13
    FORMAT: ClassVar[str] = "<I"
    layer: int


@dataclass(frozen=True)
class Execute:
    """Print ``layer`` (executed once: a repeat of an executed index is ignored)."""

    TYPE: ClassVar[int] = 0x14
    FORMAT: ClassVar[str] = "<I"
    layer: int


@dataclass(frozen=True)
class JobEnd:
    """No more layers follow in job ``job_id``."""

    TYPE: ClassVar[int] = 0x15
    FORMAT: ClassVar[str] = "<I"
    job_id: int


@dataclass(frozen=True)
class Abort:
    """Out of band: stop after the layer being printed, drop everything queued."""

    TYPE: ClassVar[int] = 0x20
    FORMAT: ClassVar[str] = "<"


@dataclass(frozen=True)
class Pause:
    """Out of band: start no new layer until RESUME (reception continues)."""

    TYPE: ClassVar[int] = 0x21
    FORMAT: ClassVar[str] = "<"


@dataclass(frozen=True)
class Resume:
    """Out of band: leave PAUSE."""

    TYPE: ClassVar[int] = 0x22
    FORMAT: ClassVar[str] = "<"


@dataclass(frozen=True)
class StatusRequest:
    """Out of band: ask for a STATUS now."""

    TYPE: ClassVar[int] = 0x23
    FORMAT: ClassVar[str] = "<"


@dataclass(frozen=True)
class Ack:
    """Controller -> host: header.ack = next expected seq (cumulative); free buffer and progress."""

    TYPE: ClassVar[int] = 0x30
    FORMAT: ClassVar[str] = "<IIIiiQ"
    credit: int
    job_id: int
    run_id: int
    last_queued: int
    last_completed: int
    held: int = 0


@dataclass(frozen=True)
class Nak:
    """Controller -> host: header.ack is expected but another frame came; ``tag`` echoes that frame's header.ack."""

    TYPE: ClassVar[int] = 0x31
    FORMAT: ClassVar[str] = "<HIBQ"
    tag: int
    credit: int
    reason: int
    held: int = 0


@dataclass(frozen=True)
class Status:
    """Controller -> host, at least once a second and on every change."""

    TYPE: ClassVar[int] = 0x32
    FORMAT: ClassVar[str] = "<IBIIiiIBi"
    boot_id: int
    state: int
    job_id: int
    run_id: int
    last_completed: int
    last_queued: int
    credit: int
    error: int
    error_layer: int


Message = (Hello | HelloAck | JobBegin | LayerBegin | Chunk | Data | LayerEnd | Execute | JobEnd
           | Abort | Pause | Resume | StatusRequest | Ack | Nak | Status)
MESSAGE_TYPES: dict[int, type] = {cls.TYPE: cls for cls in (
    Hello, HelloAck, JobBegin, LayerBegin, Chunk, Data, LayerEnd, Execute, JobEnd,
    Abort, Pause, Resume, StatusRequest, Ack, Nak, Status)}
#: Types carried in the sequenced data stream (go-back-N); all others bypass it.
DATA_TYPES = frozenset({JobBegin.TYPE, LayerBegin.TYPE, Chunk.TYPE, Data.TYPE, LayerEnd.TYPE, Execute.TYPE,
                        JobEnd.TYPE})
#: Type -> name of the bytes field that follows the fixed fields (the rest of the payload).
_TAILS = {kind: cls.TAIL for kind, cls in MESSAGE_TYPES.items() if hasattr(cls, "TAIL")}
#: Longest job name JOB_BEGIN carries and HELLO_ACK reports, bytes.
JOB_NAME_LIMIT = 64
_STRUCTS = {kind: struct.Struct(cls.FORMAT) for kind, cls in MESSAGE_TYPES.items()}


def pack_message(message: Message) -> tuple[int, bytes]:
    """(type, payload bytes) of a message."""
    kind = message.TYPE
    tail = _TAILS.get(kind)
    values = [getattr(message, f.name) for f in fields(message) if f.name != tail]
    try:
        payload = _STRUCTS[kind].pack(*values)
    except struct.error as err:
        raise ProtocolError(f"cannot pack {type(message).__name__}: {err}") from err
    if tail is not None:
        payload += getattr(message, tail)
    return kind, payload


def unpack_message(kind: int, payload: bytes) -> Message:
    """The message of type ``kind`` in ``payload``; ProtocolError on unknown type or wrong length."""
    cls = MESSAGE_TYPES.get(kind)
    if cls is None:
        raise ProtocolError(f"unknown message type 0x{kind:02x}")
    layout = _STRUCTS[kind]
    tail = _TAILS.get(kind)
    if tail is not None:
        if len(payload) < layout.size:
            raise ProtocolError(f"{cls.__name__} payload of {len(payload)} bytes is too short")
        return cls(*layout.unpack_from(payload), **{tail: bytes(payload[layout.size:])})
    if len(payload) != layout.size:
        raise ProtocolError(f"{cls.__name__} payload is {len(payload)} bytes, expected {layout.size}")
    return cls(*layout.unpack(payload))


def message_frame(message: Message, session: int, seq: int = 0, ack: int = 0,
                  version: int = PROTOCOL_VERSION) -> Frame:
    """A :class:`Frame` carrying ``message``."""
    kind, payload = pack_message(message)
    return Frame(kind, session, seq, ack, payload, version)


def seq_diff(a: int, b: int) -> int:
    """Signed distance a - b in 16-bit sequence space, in [-32768, 32767]."""
    return ((a - b + 0x8000) & 0xFFFF) - 0x8000


# --- chunk encodings -----------------------------------------------------------------


def packbits_encode(data: bytes) -> bytes:
    """PackBits (Apple TN1023, TIFF compression 32773) of ``data``, vectorised with numpy.

    Runs of 3 or more equal bytes become replicate packets, everything else literal
    packets, each at most 128 bytes. Hand-written because Pillow exposes only a PackBits
    *decoder* (its encoder is reachable only through libtiff while writing a TIFF) and
    tifffile needs the optional ``imagecodecs`` for encoding.
    """
    source = np.frombuffer(data, dtype=np.uint8)
    size = source.size
    if size == 0:
        return b""
    change = np.empty(size, dtype=bool)
    change[0] = True
    np.not_equal(source[1:], source[:-1], out=change[1:])
    run_starts = np.flatnonzero(change)
    run_lengths = np.diff(np.append(run_starts, size))
    run_is_rep = run_lengths >= 3
    # Segments: each replicate run alone; neighbouring short runs merged into one literal span.
    boundary = run_is_rep.copy()
    boundary[0] = True
    boundary[1:] |= run_is_rep[:-1]
    seg_starts = run_starts[boundary]
    seg_lengths = np.diff(np.append(seg_starts, size))
    seg_is_rep = run_is_rep[boundary]
    # Packets: split every segment into pieces of at most 128 bytes.
    pieces = (seg_lengths + 127) // 128
    first_piece = np.repeat(np.cumsum(pieces) - pieces, pieces)
    piece_in_seg = np.arange(first_piece.size) - first_piece
    pk_start = np.repeat(seg_starts, pieces) + 128 * piece_in_seg
    pk_len = np.minimum(np.repeat(seg_lengths, pieces) - 128 * piece_in_seg, 128)
    pk_rep = np.repeat(seg_is_rep, pieces)
    pk_out = np.where(pk_rep, 2, pk_len + 1)
    out_start = np.cumsum(pk_out) - pk_out
    out = np.empty(int(pk_out.sum()), dtype=np.uint8)
    out[out_start] = np.where(pk_rep, (257 - pk_len) & 0xFF, pk_len - 1)
    out[out_start[pk_rep] + 1] = source[pk_start[pk_rep]]
    lit_len = pk_len[~pk_rep]
    if lit_len.size:
        lit_first = np.cumsum(lit_len) - lit_len
        within = np.arange(int(lit_len.sum())) - np.repeat(lit_first, lit_len)
        out[np.repeat(out_start[~pk_rep] + 1, lit_len) + within] = source[np.repeat(pk_start[~pk_rep], lit_len) + within]
    return out.tobytes()


def packbits_decode(data: bytes, size: int) -> bytes:
    """Decode PackBits ``data`` to exactly ``size`` bytes with Pillow's decoder; ProtocolError if short."""
    from PIL import Image

    if size == 0:
        return b""
    try:
        return Image.frombytes("L", (size, 1), bytes(data), "packbits", "L").tobytes()
    except (ValueError, OSError, SystemError) as err:
        raise ProtocolError(f"bad PackBits data ({err})") from err


#: Largest chunk (raw bytes) for which PackBits is tried beside zlib (see :func:`encode_chunk`).
PACKBITS_BESIDE_ZLIB = 2048


def encode_chunk(raw: bytes, encodings: int) -> tuple[int, bytes]:
    """(encoding, bytes) for ``raw``: the smallest of the encodings the mask ``encodings`` allows, raw if none is
    smaller; PackBits is tried beside zlib only on chunks of at most PACKBITS_BESIDE_ZLIB bytes (the small
    frames of a noisy link, where zlib's 6 bytes of framing count; on a clean link's large chunks it almost
    never wins and costs as much time as zlib: benchmarks/README.md). A run of zero bytes (the empty rows of a
    mask, most of a droplet mask) is encoded once per length."""
    if raw == bytes(len(raw)):
        return _encode_zeros(len(raw), encodings)
    return _encode_chunk(bytes(raw), encodings)


@functools.lru_cache(maxsize=256)
def _encode_zeros(length: int, encodings: int) -> tuple[int, bytes]:
    return _encode_chunk(bytes(length), encodings)


def _encode_chunk(raw: bytes, encodings: int) -> tuple[int, bytes]:
    best_code, best = ENC_RAW, raw
    if encodings & (1 << ENC_ZLIB):
        packed = deflate(raw)
        if len(packed) < len(best):
            best_code, best = ENC_ZLIB, packed
    if encodings & (1 << ENC_PACKBITS) and (best_code != ENC_ZLIB or len(raw) <= PACKBITS_BESIDE_ZLIB):
        packed = packbits_encode(raw)
        if len(packed) < len(best):
            best_code, best = ENC_PACKBITS, packed
    return best_code, best


def deflate(raw: bytes) -> bytes:
    """A zlib stream (RFC 1950) of ``raw`` at the print's level 6 (:func:`heoslice.deflate.deflater`)."""
    return bytes(deflater(6)(raw))


def decode_chunk(encoding: int, data: bytes, raw_len: int) -> bytes:
    """The ``raw_len`` raw bytes of a chunk; ProtocolError on an unknown encoding or bad data."""
    if encoding == ENC_RAW:
        out = bytes(data)
    elif encoding == ENC_PACKBITS:
        out = packbits_decode(data, raw_len)
    elif encoding == ENC_ZLIB:
        inflater = zlib.decompressobj()
        try:
            out = inflater.decompress(data, raw_len)
        except zlib.error as err:
            raise ProtocolError(f"bad zlib data ({err})") from err
        if not inflater.eof:
            raise ProtocolError("zlib data longer than its stated raw length, or truncated")
    else:
        raise ProtocolError(f"unknown chunk encoding {encoding}")
    if len(out) != raw_len:
        raise ProtocolError(f"chunk decodes to {len(out)} bytes, header says {raw_len}")
    return out
