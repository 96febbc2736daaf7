"""Protocol codecs: CRC, COBS, frames, messages, PackBits, chunk encodings, golden frames."""

from __future__ import annotations

import re
import struct
import zlib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from heoslice.errors import HeosliceError, ProtocolError
from heoslice.printing import protocol as P

DOC = Path(__file__).resolve().parents[1] / "docs" / "protocol.md"
TN1023_RAW = bytes.fromhex("AAAAAA80002AAAAAAAAA80002A22AAAAAAAAAAAAAAAAAAAA")
TN1023_PACKED = bytes.fromhex("FEAA0280002AFDAA0380002A22F7AA")
S = 0x1234

#: name -> (message, seq, ack) exactly as listed in docs/protocol.md section 9.
GOLDEN = {
    "HELLO": (P.Hello(3, 1024, 7, 1, 0xC0FFEE01), 0, 0),
    "HELLO_ACK": (P.HelloAck(3, 0xDEADBEEF, 8192, 64, 1024, 7, 4, 20000, 20000, 600.0, 600.0, 0, 0, -1, -1, 0, 0, 1, 0),
                  0, 0),
    "HELLO_ACK_BUSY": (P.HelloAck(3, 0xDEADBEEF, 8192, 64, 1024, 7, 4, 20000, 20000, 600.0, 600.0, 0x5EED, 0xC0FFEE02,
                                  7, 9, 20, P.STATE_RECEIVING, 0, P.HELLO_BUSY, b"vase_stack"), 0, 0),
    "JOB_BEGIN": (P.JobBegin(0x5EED, 0, 20, 1, 48, 48, b"vase_stack"), 0, 1),
    "LAYER_BEGIN": (P.LayerBegin(0, 1, 24, 0x31F3F484), 1, 2),
    "CHUNK": (P.Chunk(0, 0, 0, P.ENC_PACKBITS, 24, TN1023_PACKED), 2, 3),
    "CHUNK_RAW": (P.Chunk(0, 0, 0, P.ENC_RAW, 4, b"\x00\x00\x01\x00"), 2, 4),
    "DATA": (P.Data(TN1023_RAW), 2, 8),
    "LAYER_END": (P.LayerEnd(0), 3, 5),
    "EXECUTE": (P.Execute(0), 4, 6),
    "JOB_END": (P.JobEnd(0x5EED), 5, 7),
    "ACK": (P.Ack(8100, 0x5EED, 0xC0FFEE01, 0, -1, 0), 0, 5),
    "NAK": (P.Nak(4, 8150, P.NAK_OUT_OF_ORDER, 0b101), 0, 3),
    "STATUS": (P.Status(0xDEADBEEF, P.STATE_RECEIVING, 0x5EED, 0xC0FFEE01, 0, 0, 8192, 0, -1), 0, 6),
    "ABORT": (P.Abort(), 0, 0),
}


def golden_from_doc() -> dict[str, bytes]:
    """The ```golden block of docs/protocol.md: name -> wire bytes."""
    block = re.search(r"```golden\n(.*?)```", DOC.read_text(encoding="utf-8"), re.S).group(1)
    out = {}
    for line in block.strip().splitlines():
        name, hexes = line.split(":", 1)
        out[name.strip()] = bytes.fromhex(hexes)
    return out


def test_crc_check_value():
    """CRC-32 is zlib's: the check value of '123456789' is 0xCBF43926."""
    assert P.crc32(b"123456789") == 0xCBF43926


def test_golden_frames_cover_the_document():
    """Every golden frame in the document has a message here and vice versa."""
    assert set(golden_from_doc()) == set(GOLDEN)


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_golden_frame_encodes_byte_for_byte(name):
    """Encoding the documented message gives exactly the documented wire bytes."""
    message, seq, ack = GOLDEN[name]
    assert P.encode_frame(P.message_frame(message, S, seq, ack)) == golden_from_doc()[name]


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_golden_frame_decodes_to_the_message(name):
    """Decoding the documented wire bytes gives back the documented header fields and message."""
    wire = golden_from_doc()[name]
    assert wire.endswith(b"\x00") and wire.count(0) == 1
    frame = P.decode_frame(wire[:-1])
    message, seq, ack = GOLDEN[name]
    assert (frame.version, frame.session, frame.seq, frame.ack) == (3, S, seq, ack)
    assert P.unpack_message(frame.type, frame.payload) == message


def test_golden_packbits_and_layer_crc():
    """The CHUNK's data is TN1023's PackBits example and LAYER_BEGIN's CRC is that of the raw bytes."""
    assert P.packbits_encode(TN1023_RAW) == TN1023_PACKED
    assert P.packbits_decode(TN1023_PACKED, len(TN1023_RAW)) == TN1023_RAW
    assert P.crc32(TN1023_RAW) == GOLDEN["LAYER_BEGIN"][0].crc


def test_golden_data_frame_by_hand():
    """The DATA golden frame is, independently of the codec: version 3, type 0x16, session, seq 2, tag 8,
    length 24, the 24 raw bytes, zlib's CRC-32 of all that, COBS with its zeros moved into code bytes."""
    body = bytes([3, 0x16, 0x34, 0x12, 2, 0, 8, 0, 24, 0]) + TN1023_RAW
    body += zlib.crc32(body).to_bytes(4, "little")
    blocks = body.split(b"\x00")
    assert all(len(block) < 254 for block in blocks)
    cobs = b"".join(bytes([len(block) + 1]) + block for block in blocks)
    assert golden_from_doc()["DATA"] == cobs + b"\x00"
    assert len(golden_from_doc()["DATA"]) == len(TN1023_RAW) + P.WIRE_OVERHEAD


@pytest.mark.parametrize("raw, encoded", [
    (b"", "01"),
    (b"\x00", "0101"),
    (b"\x00\x00", "010101"),
    (b"\x11\x22\x00\x33", "03112202 33".replace(" ", "")),
    (b"\x11\x00\x00\x00", "0211010101"),
    (bytes(range(1, 255)), "ff" + bytes(range(1, 255)).hex()),
    (bytes(range(0, 255)), "01ff" + bytes(range(1, 255)).hex()),
    (bytes(range(1, 256)), "ff" + bytes(range(1, 255)).hex() + "02ff"),
    (bytes(range(2, 256)) + b"\x00", "ff" + bytes(range(2, 256)).hex() + "0101"),
    (bytes(range(3, 256)) + b"\x00\x01", "fe" + bytes(range(3, 256)).hex() + "0201"),
])
def test_cobs_published_examples(raw, encoded):
    """COBS matches the published examples (Cheshire & Baker; Wikipedia's table)."""
    assert P.cobs_encode(raw).hex() == encoded
    assert P.cobs_decode(bytes.fromhex(encoded)) == raw


@given(st.binary(max_size=2000))
def test_cobs_roundtrip_has_no_zero(data):
    """COBS output never holds a zero byte, costs at most 1 byte per 254 (+1), and decodes back."""
    encoded = P.cobs_encode(data)
    assert 0 not in encoded
    assert len(encoded) <= len(data) + len(data) // 254 + 1
    assert P.cobs_decode(encoded) == data


@given(st.binary(max_size=3000).map(lambda b: bytes(np.repeat(np.frombuffer(b, np.uint8) % 4, 1 + np.frombuffer(b, np.uint8) % 7))))
def test_packbits_roundtrip(data):
    """PackBits decodes (with Pillow) to the input, for data rich in runs."""
    assert P.packbits_decode(P.packbits_encode(data), len(data)) == data


@given(st.binary(max_size=600))
def test_packbits_roundtrip_random_and_bounded(data):
    """PackBits of any bytes decodes back and never grows by more than 1 byte per 128."""
    packed = P.packbits_encode(data)
    assert len(packed) <= len(data) + (len(data) + 127) // 128
    assert P.packbits_decode(packed, len(data)) == data


def test_packbits_long_runs_split_at_128():
    """A run of 300 equal bytes becomes replicate packets of 128, 128 and 44."""
    assert P.packbits_encode(b"\x07" * 300) == bytes([129, 7, 129, 7, 213, 7])


@given(st.integers(0, 255), st.integers(0, 0xFFFF), st.integers(0, 0xFFFF), st.integers(0, 0xFFFF),
       st.binary(max_size=300))
def test_frame_roundtrip(kind, session, seq, ack, payload):
    """Any frame encodes to one delimited COBS segment and decodes to the same fields."""
    frame = P.Frame(kind, session, seq, ack, payload)
    wire = P.encode_frame(frame)
    assert wire.index(b"\x00") == len(wire) - 1
    assert len(wire) <= P.wire_size(len(payload))
    assert P.decode_frame(wire[:-1]) == frame


def test_frame_rejects_corruption():
    """A flipped bit, a truncation or a wrong length field is refused with ProtocolError."""
    wire = P.encode_frame(P.message_frame(P.Execute(7), S, 3, 4))[:-1]
    body = P.cobs_decode(wire)
    flipped = bytearray(body)
    flipped[5] ^= 0x10
    with pytest.raises(ProtocolError, match="CRC"):
        P.decode_frame(P.cobs_encode(bytes(flipped)))
    with pytest.raises(ProtocolError):
        P.decode_frame(wire[:-3])
    bad_length = bytearray(body[:-4])
    bad_length[8] = 9
    bad_length += struct.pack("<I", zlib.crc32(bytes(bad_length)))
    with pytest.raises(ProtocolError, match="payload bytes"):
        P.decode_frame(P.cobs_encode(bytes(bad_length)))


def test_protocol_error_is_a_heoslice_error():
    """ProtocolError maps to the documented exit code through HeosliceError."""
    assert issubclass(ProtocolError, HeosliceError) and ProtocolError("x").exit_code == 12


@settings(max_examples=400)
@given(st.binary(max_size=400))
def test_fuzz_frame_decoder_raises_only_protocol_error(data):
    """decode_frame on arbitrary bytes returns a Frame or raises ProtocolError, nothing else."""
    try:
        frame = P.decode_frame(data)
    except ProtocolError:
        return
    assert isinstance(frame, P.Frame)


@settings(max_examples=300)
@given(st.lists(st.binary(max_size=120), max_size=8), st.integers(0, 0xFF))
def test_fuzz_splitter_and_messages(pieces, kind):
    """The stream splitter and the message decoders survive arbitrary bytes (ProtocolError only)."""
    splitter = P.FrameSplitter(max_segment=200)
    for piece in pieces:
        for item in splitter.feed(piece):
            assert isinstance(item, (P.Frame, ProtocolError))
            if isinstance(item, P.Frame):
                try:
                    P.unpack_message(item.type, item.payload)
                except ProtocolError:
                    pass
    for piece in pieces:
        try:
            P.unpack_message(kind, piece)
        except ProtocolError:
            pass


@settings(max_examples=300)
@given(st.integers(0, 3), st.binary(max_size=200), st.integers(0, 400))
def test_fuzz_chunk_decoder(encoding, data, raw_len):
    """decode_chunk on arbitrary data returns exactly raw_len bytes or raises ProtocolError."""
    try:
        out = P.decode_chunk(encoding, data, raw_len)
    except ProtocolError:
        return
    assert len(out) == raw_len


def test_splitter_resynchronises_after_garbage():
    """Garbage, an over-long segment and a split frame do not hide the valid frames around them."""
    good = P.encode_frame(P.message_frame(P.LayerEnd(5), S, 9, 1))
    splitter = P.FrameSplitter(max_segment=100)
    items = splitter.feed(b"\x13\x37\x00" + good[:7]) + splitter.feed(good[7:] + b"\xff" * 300 + b"\x00" + good)
    frames = [item for item in items if isinstance(item, P.Frame)]
    errors = [item for item in items if isinstance(item, ProtocolError)]
    assert [P.unpack_message(f.type, f.payload) for f in frames] == [P.LayerEnd(5), P.LayerEnd(5)]
    assert len(errors) == 2


@given(st.sampled_from(sorted(GOLDEN)))
def test_message_payload_lengths_are_checked(name):
    """A message payload one byte too long or too short is refused."""
    message = GOLDEN[name][0]
    kind, payload = P.pack_message(message)
    tail = getattr(message, "TAIL", None)
    if tail is not None:
        longer = replace(message, **{tail: getattr(message, tail) + b"\x07"})
        assert P.unpack_message(kind, payload + b"\x07") == longer
        fixed = len(payload) - len(getattr(message, tail))
        if fixed:
            with pytest.raises(ProtocolError):
                P.unpack_message(kind, payload[:fixed - 1])
        return
    with pytest.raises(ProtocolError):
        P.unpack_message(kind, payload + b"\x00")
    if payload:
        with pytest.raises(ProtocolError):
            P.unpack_message(kind, payload[:-1])


def test_chunk_encoding_choice_and_raw_fallback():
    """Compressible data is encoded (smallest allowed encoding), incompressible data falls back to raw."""
    runs = bytes(500) + b"\xff" * 500
    code, packed = P.encode_chunk(runs, 1 << P.ENC_RAW | 1 << P.ENC_PACKBITS)
    assert code == P.ENC_PACKBITS and len(packed) < 40
    assert P.decode_chunk(code, packed, len(runs)) == runs
    noise = np.random.default_rng(1).integers(0, 256, 700, dtype=np.uint8).tobytes()
    assert P.encode_chunk(noise, P.ALL_ENCODINGS) == (P.ENC_RAW, noise)
    assert P.encode_chunk(runs, 1 << P.ENC_RAW) == (P.ENC_RAW, runs)
    code, packed = P.encode_chunk(runs, P.ALL_ENCODINGS)
    assert P.decode_chunk(code, packed, len(runs)) == runs


@settings(max_examples=60)
@given(st.integers(0, 20_000), st.integers(0, 20_000), st.integers(1, 255), st.booleans())
def test_a_chunk_is_encoded_the_same_whether_or_not_it_is_all_zeros(length, at, value, zeros):
    """A run of zero bytes (encoded once per length and remembered) gets what encoding it afresh gives; a chunk
    with one non-zero byte anywhere, first and last included, is encoded as itself, never as the zero run."""
    raw = bytearray(length)
    if not zeros and length:
        raw[at % length] = value
    raw = bytes(raw)
    for encodings in (P.ALL_ENCODINGS, 1 << P.ENC_RAW | 1 << P.ENC_PACKBITS):
        code, encoded = P.encode_chunk(raw, encodings)
        assert (code, encoded) == P._encode_chunk(raw, encodings)
        assert P.decode_chunk(code, encoded, length) == raw


def test_deflate_is_a_zlib_stream_with_either_encoder(monkeypatch):
    """The chunk deflater's output is an RFC 1950 stream the standard library inflates to the input, with zlib-ng
    (imagecodecs) and with the zlib fallback; with zlib allowed, PackBits is tried beside it on small chunks only
    (where zlib's 6 bytes of framing count), and wins there when it is smaller."""
    rows = np.random.default_rng(3).random((64, 40)) < 0.2
    data = bytes(300) + np.packbits(rows, axis=1).tobytes() + b"\xff" * 300
    assert zlib.decompress(P.deflate(data)) == data
    monkeypatch.setattr(P, "deflater", lambda level: lambda raw: zlib.compress(raw, level=level))
    assert P.deflate(data) == zlib.compress(data, 6)
    runs = b"\x07" * 300
    assert len(P.packbits_encode(runs)) < len(P.deflate(runs))
    assert P.encode_chunk(runs, P.ALL_ENCODINGS)[0] == P.ENC_PACKBITS
    assert P.encode_chunk(runs, 1 << P.ENC_ZLIB)[0] == P.ENC_ZLIB
    long_runs = bytes(range(1, 256)) * (P.PACKBITS_BESIDE_ZLIB // 255 + 1)
    tried = []
    monkeypatch.setattr(P, "packbits_encode", lambda raw: tried.append(len(raw)) or raw)
    assert P.encode_chunk(long_runs, P.ALL_ENCODINGS)[0] == P.ENC_ZLIB and tried == []
    P.encode_chunk(long_runs, 1 << P.ENC_PACKBITS)
    assert tried == [len(long_runs)]


def test_zlib_chunk_refuses_wrong_length():
    """A zlib chunk that inflates to more or fewer bytes than raw_len is refused."""
    packed = zlib.compress(bytes(100))
    with pytest.raises(ProtocolError):
        P.decode_chunk(P.ENC_ZLIB, packed, 99)
    with pytest.raises(ProtocolError):
        P.decode_chunk(P.ENC_ZLIB, packed, 101)
    assert P.decode_chunk(P.ENC_ZLIB, packed, 100) == bytes(100)


def test_ack_and_nak_carry_the_held_bitmap():
    """ACK and NAK round-trip the 64-bit held bitmap (SACK) and default it to 0 (plain go-back-N)."""
    full = (1 << P.SACK_SPAN) - 1
    for message in (P.Ack(100, 5, 6, 3, 2, full), P.Nak(7, 9, P.NAK_BAD_FRAME, 1 << 63), P.Ack(1, 5, 6, 2, 3)):
        kind, payload = P.pack_message(message)
        assert P.unpack_message(kind, payload) == message
    assert P.Ack(1, 5, 6, 2, 3).held == 0 and P.Nak(1, 2, 3).held == 0
    with pytest.raises(ProtocolError):
        P.pack_message(P.Ack(1, 5, 6, 2, 3, 1 << P.SACK_SPAN))


def test_seq_diff_wraps():
    """Sequence arithmetic is modulo 2^16: 1 comes 3 after 65534."""
    assert P.seq_diff(1, 65534) == 3 and P.seq_diff(65534, 1) == -3 and P.seq_diff(5, 5) == 0
