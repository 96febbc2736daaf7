"""The send window of the data stream as a pure state machine: no clock, no port, no I/O.

Go-back-N with selective acknowledgement (SACK) and credit (docs/protocol.md section 5): frames are
numbered, kept until the controller's cumulative ACK passes them, passed over on a go-back when the
controller reports them held, and resent from the oldest unacknowledged one on a NAK or a timeout.
:class:`FrameSizer` estimates the byte error rate and sizes new frames to it. Times are arguments
(seconds on any monotonic clock), so every transition can be tested by feeding events.
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from heoslice.printing import protocol as P

#: Smallest chunk payload the adaptive sizing goes down to, bytes (a 1e-2 link wants ~35).
MIN_CHUNK_PAYLOAD = 16
#: Prior of the byte error estimate: one error in this many bytes until the link shows better (frames
#: start near 250 bytes and reach the full payload after ~64 KiB sent cleanly).
ERROR_PRIOR_BYTES = 4096


@dataclass
class OutFrame:
    """One data-stream frame: seq, type, payload and credit cost; kept until acknowledged."""

    seq: int
    kind: int
    body: bytes
    cost: int
    layer: int
    payload: int
    raw: int
    sends: int = 0
    wire_end: float = 0.0
    tag: int = 0
    held: bool = False  # the controller reported it holds this frame (SACK): not resent


class SendWindow:
    """Unacknowledged frames, the next one to (re)send, credit, window, tags and the go-back rounds.

    A stateful protocol machine, so a class; every method is a transition driven by the caller.
    """

    def __init__(self) -> None:
        self.frames: deque[OutFrame] = deque()
        self.send_idx = 0
        self.next_seq = 0
        self.credit = 0
        self.window = 1
        self.sack = False
        self.stuck = 0  # consecutive go-back rounds without the acknowledgement advancing
        self.backoff = 1
        self.await_resend = False
        self.tag = 0

    def configure(self, window: int, credit: int, sack: bool) -> None:
        """Take a session's negotiated window (frames), credit (bytes) and SACK."""
        self.window = max(1, min(window, P.SACK_SPAN if sack else 0x7FFF))
        self.credit = credit
        self.sack = sack

    def restart(self) -> None:
        """A fresh data stream (seq 0): forget every frame; the consecutive-rounds count is kept."""
        self.frames.clear()
        self.send_idx = 0
        self.next_seq = 0
        self.await_resend = False
        self.backoff = 1

    @property
    def drained(self) -> bool:
        """True when no frame waits to be (re)sent: the next one must come from the message stream."""
        return self.send_idx >= len(self.frames)

    @property
    def empty(self) -> bool:
        """True when every frame is acknowledged."""
        return not self.frames

    @property
    def in_flight(self) -> bool:
        """True when frames of this pass are sent and unacknowledged."""
        return self.send_idx > 0

    @property
    def head(self) -> OutFrame | None:
        """The oldest unacknowledged frame."""
        return self.frames[0] if self.frames else None

    def push(self, kind: int, body: bytes, layer: int, raw: int) -> OutFrame:
        """Number a new frame (the next seq) and keep it until acknowledged."""
        out = OutFrame(self.next_seq, kind, body, len(body) + P.FRAME_OVERHEAD, layer, len(body), raw)
        self.next_seq = (self.next_seq + 1) % P.SEQ_MODULUS
        self.frames.append(out)
        return out

    def credit_used(self) -> int:
        """Bytes of credit used: costs of the frames sent in this pass that the controller does not report held."""
        return sum(out.cost for out in itertools.islice(self.frames, self.send_idx) if not out.held)

    def next_to_send(self) -> tuple[OutFrame | None, int]:
        """(frame, held frames passed over) to transmit next within window and credit, or (None, n)."""
        skipped = 0
        while self.send_idx < len(self.frames) and self.send_idx < self.window:
            out = self.frames[self.send_idx]
            if not out.held:
                return (out if self.credit_used() + out.cost <= self.credit else None), skipped
            self.send_idx += 1
            skipped += 1
        return None, skipped

    def can_take_new(self) -> bool:
        """True when a new frame appended now would be inside the window."""
        return self.drained and self.send_idx < self.window

    def mark_sent(self, out: OutFrame, wire_end: float) -> bool:
        """Record a transmission of ``out`` (the frame at the send index); True when it was a retransmission."""
        self.tag = (self.tag + 1) & 0xFFFF
        out.tag = self.tag
        out.wire_end = wire_end
        if self.send_idx == 0:
            self.await_resend = False
        resent = out.sends > 0
        out.sends += 1
        self.send_idx += 1
        return resent

    def on_ack(self, ack_seq: int, credit: int, held: int | None = None) -> bool:
        """Cumulative acknowledgement of every frame before ``ack_seq`` with fresh credit; True when it advanced.

        ``held`` (ACK and NAK, with SACK): bit i tells that the controller holds seq ack_seq + 1 + i.
        """
        progressed = False
        while self.frames and P.seq_diff(ack_seq, self.frames[0].seq) > 0:
            self.frames.popleft()
            if self.send_idx > 0:
                self.send_idx -= 1
            progressed = True
        if progressed:
            self.stuck = 0
            self.backoff = 1
        if self.frames and P.seq_diff(ack_seq, self.frames[0].seq) == 0:
            self.frames[0].held = False
            if held is not None and self.sack:
                for out in itertools.islice(self.frames, 1, P.SACK_SPAN + 1):
                    out.held = bool(held >> (P.seq_diff(out.seq, ack_seq) - 1) & 1)
        if not self.frames or P.seq_diff(ack_seq, self.frames[0].seq) == 0 or progressed:
            self.credit = credit
        return progressed

    def go_back(self) -> int:
        """Rewind to the oldest unacknowledged frame; the count of consecutive rounds without progress."""
        self.send_idx = 0
        self.await_resend = True
        self.stuck += 1
        return self.stuck

    def nak_calls_for_go_back(self, expected: int, tag: int) -> bool:
        """True when a NAK naming ``expected`` with ``tag`` should rewind the stream.

        Every data frame carries a transmission tag; a NAK echoes the tag of the frame that provoked
        it (as TCP's timestamp echo does). A tag older than the resent frame's own tag belongs to the
        flight already rewound, so it is ignored, as is a NAK while a rewind is not yet resent.
        """
        if not self.frames or P.seq_diff(expected, self.frames[0].seq) != 0 or self.await_resend:
            return False
        return P.seq_diff(tag, self.frames[0].tag) >= 0

    def timed_out(self, now: float, ack_timeout_s: float, max_backoff: int) -> bool:
        """True (and the backoff doubled) when the oldest frame in flight is unacknowledged too long after it left."""
        if self.send_idx == 0 or now <= self.frames[0].wire_end + ack_timeout_s * self.backoff:
            return False
        self.backoff = min(self.backoff * 2, max_backoff)
        return True


def optimal_frame_bytes(error_rate: float, overhead: int, largest: int, waste: float = 1.0,
                        smallest_payload: int = MIN_CHUNK_PAYLOAD) -> int:
    """Frame size L (wire bytes) maximising throughput at byte error rate ``e``, within [.., largest].

    Efficiency = (1 - p) / (1 + waste p) * (L - overhead - L // 254) / L with frame error
    rate p = 1 - (1 - e)^L, where ``waste`` frames are resent in vain after each error (about
    1 for plain go-back-N, 0 when the controller holds what follows a gap) and L // 254 is COBS.
    """
    smallest = overhead + smallest_payload
    if error_rate <= 0 or largest <= smallest:
        return max(largest, smallest)
    sizes = np.arange(smallest, largest + 1, dtype=float)
    good = np.exp(sizes * math.log1p(-min(error_rate, 0.5)))
    efficiency = good / (1 + waste * (1 - good)) * (sizes - overhead - sizes // 254) / sizes
    return int(sizes[int(np.argmax(efficiency))])


class FrameSizer:
    """The payload size of new data frames, from the byte error rate the retransmissions reveal.

    The rate is estimated from retransmissions per byte sent (each resend means an earlier copy
    was lost; with the prior of one in ``ERROR_PRIOR_BYTES``) as e = -ln(1 - p) / L, p the
    resends per frame of mean size L; the frame size is then chosen by :func:`optimal_frame_bytes`.
    Re-estimated every 32 chunks and after every retransmission round.
    """

    def __init__(self) -> None:
        self.events = 0.0
        self.bytes = 0.0
        self.frames = 0.0
        self._budget: int | None = None
        self._age = 0

    def on_sent(self, wire_bytes: int, resent: bool = False, sack: bool = True) -> None:
        """A frame of ``wire_bytes`` was written (``resent``: again, so an earlier copy was lost).

        Without SACK about half the resends follow a loss in vain (the frame behind the lost one), so a
        resend counts half an error there.
        """
        self.bytes += wire_bytes
        self.frames += 1
        self.events += resent * (1.0 if sack else 0.5)

    def on_error(self) -> None:
        """A retransmission round: estimate again; old evidence is halved past 256 KiB."""
        self._budget = None
        if self.bytes > 1 << 18:
            self.bytes /= 2
            self.events /= 2
            self.frames /= 2

    def invalidate(self) -> None:
        """Recompute at the next call (the link's payload limit changed)."""
        self._budget = None

    def error_rate(self) -> float:
        """Estimated byte error rate."""
        per_byte = (self.events + 1) / (self.bytes + ERROR_PRIOR_BYTES)
        mean = self.bytes / self.frames if self.frames else 1.0
        return -math.log1p(-min(per_byte * mean, 0.5)) / mean

    def budget(self, link_payload: int, sack: bool, count: bool = True) -> int:
        """Payload bytes for the next data frame, at most ``link_payload`` (``count`` False: only look)."""
        self._age += count
        if self._budget is None or self._age >= 32:
            frame = optimal_frame_bytes(self.error_rate(), P.WIRE_OVERHEAD, P.wire_size(link_payload),
                                        waste=0.0 if sack else 1.0)
            self._budget = max(MIN_CHUNK_PAYLOAD, frame - P.WIRE_OVERHEAD - frame // 254)
            self._age = 0
        return min(self._budget, link_payload)
