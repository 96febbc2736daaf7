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
#: Largest share of frames a chosen frame size may lose: one frame failing the retry cap's 12 rounds in a
#: row then happens about 3 times in a million frames (0.35^12), not once in a few thousand.
MAX_FRAME_LOSS = 0.35
#: Prior of the byte error estimate: one error in this many bytes until the link shows better (frames
#: start near 250 bytes and reach the full payload after ~64 KiB sent cleanly).
ERROR_PRIOR_BYTES = 4096
#: Frames acknowledged before a size cap set after repeated failures (FrameSizer.cap) is lifted.
CEILING_FRAMES = 32


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

    def behind_head(self) -> int:
        """Bytes of the frames sent in this pass after the oldest unacknowledged one (resent in vain by a go-back
        without SACK)."""
        return sum(out.cost for out in itertools.islice(self.frames, 1, self.send_idx))

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
                        smallest_payload: int = MIN_CHUNK_PAYLOAD, waste_bytes: float = 0.0,
                        max_loss: float = 1.0) -> int:
    """Frame size L (wire bytes) maximising throughput at byte error rate ``e``, within [.., largest].

    Efficiency = (1 - p) / (1 + w p) * (L - overhead - L // 254) / L with frame error rate
    p = 1 - (1 - e)^L and w = ``waste`` + ``waste_bytes`` / L the frames resent in vain after each
    error: ``waste`` frames (about 1 for plain go-back-N, 0 when the controller holds what follows a gap)
    and ``waste_bytes`` bytes (what go-back-N had sent behind a lost frame when it learnt of the loss,
    however it was cut into frames); L // 254 is COBS. Sizes losing more than ``max_loss`` of their
    frames are left out (but the smallest).
    """
    smallest = overhead + smallest_payload
    if error_rate <= 0 or largest <= smallest:
        return max(largest, smallest)
    sizes = np.arange(smallest, largest + 1, dtype=float)
    good = np.exp(sizes * math.log1p(-min(error_rate, 0.5)))
    vain = waste + waste_bytes / sizes
    efficiency = good / (1 + vain * (1 - good)) * (sizes - overhead - sizes // 254) / sizes
    efficiency[1:][good[1:] < 1 - max_loss] = -1.0
    return int(sizes[int(np.argmax(efficiency))])


class FrameSizer:
    """The payload size of new data frames, from the byte error rate the retransmissions reveal.

    With SACK every resend means an earlier copy was lost: the rate is resends per byte sent, e = -ln(1 - p) / L,
    p the resends per frame of mean size L. Plain go-back-N also resends the frames behind a loss, in vain, so
    there the losses are the go-back rounds and p = rounds / (rounds + frames acknowledged), L the mean size of
    those frames and of the lost ones; the bytes it had sent behind each loss (measured per round) are the waste
    :func:`optimal_frame_bytes` weighs. Both start from a prior of one error in ``ERROR_PRIOR_BYTES``, halved with
    the old evidence (a prior of fixed weight held the estimate at half a 1e-2 link's rate). Re-estimated every 32
    chunks and after every retransmission round.
    """

    def __init__(self) -> None:
        self.events = 0.0
        self.bytes = 0.0
        self.frames = 0.0
        self.rounds = 0.0
        self.acked = 0.0
        self.tried_bytes = 0.0  # bytes of the frames acknowledged and of the lost frames a go-back resent from
        self.wasted = 0.0
        self.prior = 1.0  # weight of the ERROR_PRIOR_BYTES prior, halved with the evidence
        self.ceiling: int | None = None  # payload cap after a chunk kept failing (see cap), bytes
        self._acked_since_cap = 0
        self._budget: int | None = None
        self._age = 0

    def on_sent(self, wire_bytes: int, resent: bool = False) -> None:
        """A frame of ``wire_bytes`` was written (``resent``: again, so an earlier copy was lost with SACK)."""
        self.bytes += wire_bytes
        self.frames += 1
        self.events += resent

    def on_acked(self, frames: int, frame_bytes: int) -> None:
        """``frames`` data frames of ``frame_bytes`` in all were acknowledged (each once)."""
        self.acked += frames
        self.tried_bytes += frame_bytes
        if self.ceiling is not None:
            self._acked_since_cap += frames
            if self._acked_since_cap >= CEILING_FRAMES:
                self.ceiling = None

    def cap(self, payload: int) -> None:
        """Make chunks of at most ``payload`` bytes (not below MIN_CHUNK_PAYLOAD) until CEILING_FRAMES frames
        are acknowledged: a chunk within the budget that keeps failing shows a link worse than the estimate,
        which lags it by many rounds."""
        self.ceiling = max(MIN_CHUNK_PAYLOAD, payload)
        self._acked_since_cap = 0

    def on_error(self, wasted_bytes: float = 0.0, lost_bytes: float = 0.0) -> None:
        """A retransmission round from a lost frame of ``lost_bytes``, ``wasted_bytes`` sent behind it: estimate
        again; old evidence is halved past 256 KiB."""
        self._budget = None
        self.rounds += 1
        self.wasted += wasted_bytes
        self.tried_bytes += lost_bytes
        if self.bytes > 1 << 18:
            for name in ("bytes", "events", "frames", "rounds", "acked", "tried_bytes", "wasted", "prior"):
                setattr(self, name, getattr(self, name) / 2)

    def invalidate(self) -> None:
        """Recompute at the next call (the link's payload limit changed)."""
        self._budget = None

    def error_rate(self, sack: bool = True) -> float:
        """Estimated byte error rate."""
        if sack:
            mean = self.bytes / self.frames if self.frames else 1.0
            per_frame = (self.events + self.prior) / (self.bytes + self.prior * ERROR_PRIOR_BYTES) * mean
        else:
            tries = self.rounds + self.acked
            mean = self.tried_bytes / tries if tries else 1.0
            per_frame = (self.rounds + self.prior) / (tries + self.prior * ERROR_PRIOR_BYTES / mean)
        return -math.log1p(-min(per_frame, 0.5)) / mean

    def waste_bytes(self) -> float:
        """Mean bytes go-back-N had sent behind a lost frame when it went back (prior: none)."""
        return self.wasted / self.rounds if self.rounds else 0.0

    def budget(self, link_payload: int, sack: bool, count: bool = True) -> int:
        """Payload bytes for the next data frame, at most ``link_payload`` (``count`` False: only look)."""
        self._age += count
        if self._budget is None or self._age >= 32:
            frame = optimal_frame_bytes(self.error_rate(sack), P.WIRE_OVERHEAD, P.wire_size(link_payload),
                                        waste=0.0 if sack else 1.0, waste_bytes=0.0 if sack else self.waste_bytes(),
                                        max_loss=MAX_FRAME_LOSS)
            self._budget = max(MIN_CHUNK_PAYLOAD, frame - P.WIRE_OVERHEAD - frame // 254)
            self._age = 0
        return min(self._budget, link_payload, self.ceiling or link_payload)
