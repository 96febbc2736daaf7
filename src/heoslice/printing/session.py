"""One connection to a controller: the port's bytes, paced writes, the HELLO handshake, out-of-band messages.

A :class:`Session` owns the open port and the session id (docs/protocol.md section 2); it turns a failing
or silent port into :class:`LinkLost` so the job above it can reconnect, and paces writes to the line rate
(section 5, "Pacing") so little waits in OS buffers.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from heoslice.errors import IncompatibleControllerError, LinkDeadError, ProtocolError
from heoslice.printing import protocol as P
from heoslice.printing.ports import Connector, Port


@dataclass(frozen=True)
class LinkTiming:
    """Host timing, seconds; the dead-link bound is ``silence_s + reconnect_s`` after the controller last
    answered (4 s by default), whatever the host was doing (PrinterLink._dead_by)."""

    hello_timeout_s: float = 3.0  # first handshake: give up (no controller) after this
    hello_interval_s: float = 0.25  # HELLO repeat period
    ack_timeout_s: float = 0.25  # beyond the modelled wire time of the oldest unacked frame
    max_backoff: int = 8  # timeout multiplier cap (doubles per timeout)
    retry_limit: int = 12  # consecutive retransmission rounds without progress before pausing
    silence_s: float = 2.5  # no valid frame for this long: the link is suspect, reconnect
    reconnect_s: float = 1.5  # reconnecting for this long without an answer: the link is dead
    abort_wait_s: float = 1.0  # how long PAUSE / RESUME wait for the controller's confirmation (ABORT: +1 s)
    poll_s: float = 0.005  # read granularity
    keepalive_s: float = 1.0  # nothing written for this long: STATUS_REQ (the controller's lease on us)
    stall_s: float = 5.0  # nothing acknowledged or progressing while nothing is queued: a stuck controller
    head_stall_s: float = 120.0  # no layer completed for this long while layers are queued
    max_reconnects: int = 8  # per job, not per connection
    max_resplits: int = 32  # new sessions opened to shrink frames, per job


class LinkLost(Exception):
    """The port failed or fell silent; the job reconnects."""


class Session:
    """The open port, its session id and write pacing (a connection's mutable state, so a class)."""

    def __init__(self, connector: Connector, timing: LinkTiming, hello: P.Hello, session_seed: int | None = None):
        self.connector, self.timing, self.hello = connector, timing, hello
        self.name = connector.name
        self._rng = np.random.default_rng(session_seed)
        self.port: Port | None = None
        self.id = 0
        self.rate: float | None = None  # bytes/s the writes are paced to (None: unpaced)
        self.wire_busy = 0.0  # when the bytes written so far will have left the wire
        self.last_rx = 0.0
        self.last_tx = 0.0
        self._splitter = P.FrameSplitter()

    # -- the port ----------------------------------------------------------------------

    def open(self) -> None:
        """Open the port; reset the frame splitter, the silence timer and the pacing rate."""
        self.port = self.connector.open()
        baud = getattr(self.connector, "baud", None)
        self.rate = baud / 10.0 if baud else None
        self._splitter = P.FrameSplitter()
        self.last_rx = time.monotonic()
        self.wire_busy = 0.0

    def close(self) -> None:
        """Close the port, ignoring errors of a port already broken."""
        if self.port is not None:
            try:
                self.port.close()
            except Exception:  # noqa: BLE001 - closing a broken port must not hide the real error
                pass
            self.port = None

    def write(self, data: bytes) -> None:
        """Write bytes; a failing port (or one whose peer stopped reading) becomes LinkLost."""
        import serial

        try:
            self.port.write(data)
        except (serial.SerialException, OSError) as err:
            raise LinkLost(f"cannot write ({' '.join(str(err).split())})") from err
        self.last_tx = time.monotonic()

    def keepalive(self, now: float) -> None:
        """STATUS_REQ when nothing was written for ``keepalive_s``, so the controller knows this host is live."""
        if self.id and now - self.last_tx > self.timing.keepalive_s:
            self.write(P.encode_frame(P.message_frame(P.StatusRequest(), self.id)))

    def waiting(self) -> int:
        """Bytes ready to read (LinkLost when the port has failed)."""
        import serial

        try:
            return self.port.in_waiting
        except (serial.SerialException, OSError) as err:
            raise LinkLost(str(err)) from err

    def read_frames(self, block: bool = True) -> list[P.Frame]:
        """Valid frames among the bytes waiting now (invalid ones are dropped; the sender retransmits); ``block``:
        when nothing waits, wait for a byte up to the port's timeout."""
        import serial

        try:
            waiting = self.port.in_waiting
            if not waiting and not block:
                return []
            data = self.port.read(max(1, waiting))
        except (serial.SerialException, OSError) as err:
            raise LinkLost(str(err)) from err
        if not data:
            return []
        frames = [item for item in self._splitter.feed(data) if not isinstance(item, ProtocolError)]
        if frames:
            self.last_rx = time.monotonic()
        return frames

    # -- pacing ------------------------------------------------------------------------

    def pacing_wait(self, now: float, lead_s: float | None = None) -> float | None:
        """When the next write may go (None: now): bytes written must leave the wire within ``lead_s`` (default
        ``poll_s``)."""
        lead = self.timing.poll_s if lead_s is None else lead_s
        if self.rate and self.wire_busy - now > lead:
            return self.wire_busy - lead
        return None

    def send(self, wire: bytes, now: float) -> float:
        """Write a frame's wire bytes; return when they will have left the wire (modelled)."""
        self.write(wire)
        byte_time = 1.0 / self.rate if self.rate else 0.0
        self.wire_busy = max(self.wire_busy, now) + len(wire) * byte_time
        return self.wire_busy

    # -- handshake and out-of-band messages ---------------------------------------------

    def handshake(self, deadline: float, first: bool, since: float | None = None) -> P.HelloAck:
        """HELLO until HELLO_ACK (new session); raise on silence (``since``: when the controller last answered
        before), echo or another protocol version."""
        since = time.monotonic() if since is None else since
        self.id = int(self._rng.integers(1, 1 << 16))
        hello = P.encode_frame(P.message_frame(self.hello, self.id))
        next_hello = 0.0
        while True:
            now = time.monotonic()
            if now >= deadline:
                what = (f"no controller answered (no HELLO_ACK within {self.timing.hello_timeout_s:g} s)" if first
                        else f"the controller stopped answering (no answer for {now - since:.1f} s, "
                             "HELLO unanswered)")
                raise LinkDeadError(f"{self.name}: {what}; check the port, cable, power and baud rate")
            if now >= next_hello:
                self.write(hello)
                next_hello = now + self.timing.hello_interval_s
            for frame in self.read_frames():
                ack = self._hello_reply(frame)
                if ack is not None:
                    return ack

    def _hello_reply(self, frame: P.Frame) -> P.HelloAck | None:
        """The HELLO_ACK of this session in ``frame``, None for anything else; raise on an echo or another version."""
        if frame.type == P.Hello.TYPE:
            raise IncompatibleControllerError(
                f"{self.name}: received our own HELLO back: the port echoes (a loopback?), no controller")
        if frame.type != P.HelloAck.TYPE:
            return None
        if frame.version != P.PROTOCOL_VERSION:
            raise IncompatibleControllerError(
                f"{self.name}: the controller speaks protocol version {frame.version}, heoslice speaks "
                f"version {P.PROTOCOL_VERSION}; update the controller firmware or heoslice")
        if frame.session != self.id:
            return None
        try:
            return P.unpack_message(frame.type, frame.payload)
        except ProtocolError:
            return None

    def out_of_band(self, message: P.Message, wanted_state: int, wait_s: float | None = None) -> P.Status | None:
        """Send an out-of-band message until a STATUS of this session shows ``wanted_state``; that STATUS or None."""
        if self.port is None or not self.id:
            return None
        wire = P.encode_frame(P.message_frame(message, self.id))
        deadline = time.monotonic() + (self.timing.abort_wait_s if wait_s is None else wait_s)
        next_send = 0.0
        try:
            while time.monotonic() < deadline:
                if time.monotonic() >= next_send:
                    self.write(wire)
                    next_send = time.monotonic() + 0.25
                for frame in self.read_frames():
                    if frame.type == P.Status.TYPE and frame.session == self.id:
                        try:
                            status = P.unpack_message(frame.type, frame.payload)
                        except ProtocolError:
                            continue
                        if status.state == wanted_state:
                            return status
        except LinkLost:
            return None
        return None
