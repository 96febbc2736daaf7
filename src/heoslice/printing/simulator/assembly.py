"""A layer being received by the simulated controller: its channels written by CHUNK and DATA, then checked.

Each write returns whether it was valid; an invalid one (outside the layer, undecodable) is the
controller's error 1 (docs/protocol.md section 4).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from heoslice.errors import ProtocolError
from heoslice.printing import protocol as P


@dataclass
class LayerAssembly:
    """The channels of one layer concatenated in ``data`` (channel c at c * size) and the DATA write cursor."""

    index: int
    channels: int
    size: int
    crc: int
    data: bytearray = field(default_factory=bytearray)
    cursor: int = 0
    complete: bool = False
    crc_received: int = -1  # CRC-32 of the data actually received, set at LAYER_END

    @classmethod
    def begin(cls, message: P.LayerBegin) -> "LayerAssembly":
        """An empty layer as LAYER_BEGIN announces it."""
        return cls(message.layer, message.channels, message.size, message.crc,
                   bytearray(message.channels * message.size))

    def write_chunk(self, message: P.Chunk) -> bool:
        """Decode and write a CHUNK at its address; the cursor moves past it. False when invalid."""
        if message.channel >= self.channels or message.offset + message.raw_len > self.size:
            return False
        try:
            raw = P.decode_chunk(message.encoding, message.data, message.raw_len)
        except ProtocolError:
            return False
        start = message.channel * self.size + message.offset
        self.data[start:start + len(raw)] = raw
        self.cursor = start + len(raw)
        return True

    def write_data(self, message: P.Data) -> bool:
        """Write a DATA at the cursor and advance it. False when it would reach past the layer."""
        if self.cursor + len(message.data) > len(self.data):
            return False
        self.data[self.cursor:self.cursor + len(message.data)] = message.data
        self.cursor += len(message.data)
        return True

    def finish(self) -> bool:
        """LAYER_END: True (and complete) when the received bytes have LAYER_BEGIN's CRC."""
        actual = P.crc32(self.data)
        if actual != self.crc:
            return False
        self.crc_received = actual
        self.complete = True
        return True
