"""The host side of ``heoslice print``: stream a job's layers to a controller over a serial link.

A :class:`PrinterLink` drives one job over any pyserial port (a device path, or a URL
such as ``socket://host:port``; ``sim://?...`` starts the built-in simulator in this
process): handshake, credit-limited go-back-N sending with paced writes (passing over
frames the controller holds when both sides enable SACK), frames sized to the observed
error rate, retransmission with backoff and a retry cap, STATUS handling, reconnect and
resume while the controller keeps its boot id, and a JSON-lines print log. Layers come from a
``get_layer(index) -> channel payloads`` function, so a resume can re-read any layer;
:func:`stack_job` builds one from a verified stack. Protocol: ``docs/protocol.md``.
"""

from __future__ import annotations

import datetime as _dt
import itertools
import json
import math
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from heoslice import protocol as P
from heoslice.errors import (ControllerFaultError, ControllerResetError, IncompatibleControllerError,
                             InputError, LinkDeadError, PortError, PrintInterrupted, ProtocolError,
                             RetryLimitError)

LayerSource = Callable[[int], Sequence[bytes]]
#: Smallest chunk payload the adaptive sizing goes down to, bytes.
MIN_CHUNK_PAYLOAD = 64
#: Prior of the byte error estimate: one error in this many bytes until the link shows better (frames
#: start near 250 bytes and reach the full payload after ~64 KiB sent cleanly). A frame keeps its size
#: when resent, so opening with full-size frames on a noisy link would resend kilobytes many times.
ERROR_PRIOR_BYTES = 4096
#: Bytes a CHUNK adds to the frame before its data (a DATA adds none).
CHUNK_HEADER = 12


@dataclass(frozen=True)
class JobSpec:
    """A print job: ``layer_count`` layers of ``channels`` bit-packed masks of ``width`` x ``height`` pixels."""

    job_id: int
    layer_count: int
    channels: int
    width: int
    height: int

    @property
    def channel_bytes(self) -> int:
        """Bytes of one channel of one layer: rows packed MSB first, each padded to whole bytes."""
        return self.height * ((self.width + 7) // 8)


@dataclass(frozen=True)
class LinkTiming:
    """Host timing, seconds; the dead-link bound is ``silence_s + reconnect_s`` (< 5 s by default)."""

    hello_timeout_s: float = 3.0  # first handshake: give up (no controller) after this
    hello_interval_s: float = 0.25  # HELLO repeat period
    ack_timeout_s: float = 0.25  # beyond the modelled wire time of the oldest unacked frame
    max_backoff: int = 8  # timeout multiplier cap (doubles per timeout)
    retry_limit: int = 12  # consecutive retransmission rounds without progress before pausing
    silence_s: float = 2.5  # no valid frame for this long: the link is suspect, reconnect
    reconnect_s: float = 1.5  # reconnecting for this long without an answer: the link is dead
    abort_wait_s: float = 1.0  # how long ABORT / PAUSE wait for the controller's confirmation
    poll_s: float = 0.005  # read granularity


@dataclass(frozen=True)
class Progress:
    """Passed to ``on_progress`` after each executed layer."""

    layer: int
    layers_done: int
    layers_total: int
    bytes_sent: int
    elapsed_s: float


@dataclass(frozen=True)
class PrintResult:
    """What a finished print did; bytes are wire bytes host -> controller."""

    first_layer: int
    last_completed: int
    layers_printed: int
    bytes_sent: int
    payload_bytes: int
    raw_bytes: int
    frames_sent: int
    frames_retransmitted: int
    timeouts: int
    naks: int
    reconnects: int
    elapsed_s: float
    boot_id: int
    frames_skipped: int = 0  # retransmissions saved: frames the controller reported held (SACK)
    sack: bool = False  # selective acknowledgement negotiated (in the last session)


def pack_mask(mask: np.ndarray) -> bytes:
    """Channel payload of a (height, width) bool mask: ``np.packbits`` along rows (MSB first, rows padded)."""
    return np.packbits(np.asarray(mask, dtype=bool), axis=1).tobytes()


def default_log_path(stack: Path) -> Path:
    """The print log beside a stack directory: ``<stack>.print-log.jsonl``."""
    stack = Path(stack).resolve()
    return stack.with_name(stack.name + ".print-log.jsonl")


def stack_job(directory: Path) -> tuple[JobSpec, LayerSource]:
    """Verify a stack (VerifyError if it fails) and return its job and layer source.

    Channel 0 is the solid mask; channels 1.. are the droplet masks of a layer entry's
    ``"channels"`` list when present (layers with fewer channels are padded with empty masks).
    """
    from heoslice.stack import decode_mask, load_verified, read_layer_mask, resolve_inside

    directory = Path(directory)
    manifest = load_verified(directory)
    layers = manifest["layers"]
    if not layers:
        raise InputError(f"{directory}: the stack has no layers")
    width, height = manifest["image"]["width"], manifest["image"]["height"]
    channels = 1 + max(len(entry.get("channels") or []) for entry in layers)
    job_id = P.crc32(json.dumps(manifest, sort_keys=True).encode()) or 1
    job = JobSpec(job_id, len(layers), channels, width, height)
    as_nonzero = {**manifest, "mask": "nonzero"}

    def get_layer(index: int) -> list[bytes]:
        out = [pack_mask(read_layer_mask(directory, manifest, index))]
        for channel in layers[index].get("channels") or []:
            out.append(pack_mask(decode_mask(resolve_inside(directory, channel["file"]), as_nonzero,
                                             sha256=channel["sha256"])))
        empty = bytes(job.channel_bytes)
        return out + [empty] * (channels - len(out))

    return job, get_layer


def synthetic_job(layer_count: int, width: int = 64, height: int = 16, channels: int = 1,
                  seed: int = 0, job_id: int = 0x5EED) -> tuple[JobSpec, LayerSource]:
    """A job of random blob masks (compressible, distinct per layer) for tests and benchmarks."""
    job = JobSpec(job_id, layer_count, channels, width, height)

    def get_layer(index: int) -> list[bytes]:
        rng = np.random.default_rng([seed, index])
        out = []
        for _ in range(channels):
            yy, xx = np.mgrid[0:height, 0:width]
            cx, cy, r = rng.uniform(0, width), rng.uniform(0, height), rng.uniform(2, max(width, height) / 2)
            out.append(pack_mask((xx - cx) ** 2 + (yy - cy) ** 2 < r * r))
        return out

    return job, get_layer


def random_job(layer_count: int, rows: int, seed: int = 0, job_id: int = 0xBEEF) -> tuple[JobSpec, LayerSource]:
    """A one-channel job of incompressible random layers, 2048 px wide and ``rows`` high (256 bytes a row)."""
    job = JobSpec(job_id, layer_count, 1, 2048, rows)
    layer_bytes = job.channel_bytes

    def get_layer(index: int) -> list[bytes]:
        return [np.random.default_rng([seed, index]).integers(0, 256, layer_bytes, dtype=np.uint8).tobytes()]

    return job, get_layer


# --- ports -----------------------------------------------------------------------------


class SerialConnector:
    """Opens a pyserial port (device path or URL) on demand; used again to reconnect."""

    def __init__(self, port: str, baud: int):
        self.name, self.baud = port, baud

    def open(self):
        """A fresh open port (PortError when it cannot be opened)."""
        import serial

        try:
            handle = serial.serial_for_url(self.name, baudrate=self.baud, timeout=0.005, write_timeout=5)
        except (serial.SerialException, OSError, ValueError) as err:
            raise PortError(f"{self.name}: cannot open port ({' '.join(str(err).split())})") from err
        try:
            handle.reset_input_buffer()
        except (serial.SerialException, OSError):
            pass
        return handle

    def close(self) -> None:
        """Nothing held between connections."""


class SimConnector:
    """A ``sim://`` port: a :class:`~heoslice.controller.SimController` on a thread of this process."""

    def __init__(self, controller, name: str = "sim://"):
        self.controller, self.name = controller, name
        self.baud = controller.config.baud / max(controller.config.time_scale, 1e-12)
        self._started = False

    def open(self):
        """A fresh open port (PortError when it cannot be opened)."""
        from heoslice.controller import pipe_pair

        port, transport = pipe_pair(self.name)
        port.timeout = 0.005
        self.controller.attach(transport)
        if not self._started:
            self.controller.start()
            self._started = True
        return port

    def close(self) -> None:
        if self._started:
            self.controller.stop()
            self._started = False


def connector_for(port: str, baud: int):
    """The connector for a port argument: ``sim://?options`` runs the simulator, anything else is pyserial's."""
    if port.lower().startswith("sim://"):
        from heoslice.controller import SimController, sim_from_url

        config, faults = sim_from_url(port)
        return SimConnector(SimController(config, faults), port)
    return SerialConnector(port, baud)


class PrintLog:
    """Append-only JSON lines: one object per event, flushed at once (a lab's trace of what was printed)."""

    def __init__(self, path: Path | None):
        self.path = path
        self._handle = None
        if path is not None:
            try:
                self._handle = open(path, "a", encoding="utf-8")
            except OSError as err:
                from heoslice.errors import OutputError

                raise OutputError(f"{path}: cannot write the print log ({err.strerror})") from err

    def write(self, event: str, **fields) -> None:
        if self._handle is None:
            return
        record = {"time": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds"),
                  "event": event, **fields}
        self._handle.write(json.dumps(record, sort_keys=False) + "\n")
        self._handle.flush()

    def close(self) -> None:
        if self._handle is not None:
            self._handle.close()
            self._handle = None


# --- the link --------------------------------------------------------------------------


@dataclass
class _Out:
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


@dataclass
class _Counters:
    """Running totals of a print, and per-layer bytes and retransmissions until the layer is logged."""

    bytes_sent: int = 0
    payload_bytes: int = 0
    raw_bytes: int = 0
    frames_sent: int = 0
    retransmitted: int = 0
    skipped: int = 0
    timeouts: int = 0
    naks: int = 0
    reconnects: int = 0
    layer_bytes: dict = field(default_factory=dict)
    layer_retries: dict = field(default_factory=dict)


class _LinkLost(Exception):
    """Internal: the port failed or fell silent; reconnect."""


def optimal_frame_bytes(error_rate: float, overhead: int, largest: int, waste: float = 1.0) -> int:
    """Frame size L (wire bytes) maximising throughput at byte error rate ``e``, within [.., largest].

    Efficiency = (1 - p) / (1 + waste p) * (L - overhead - L // 254) / L with frame error
    rate p = 1 - (1 - e)^L, where ``waste`` frames are resent in vain after each error (about
    1 for plain go-back-N, 0 when the controller holds what follows a gap) and L // 254 is COBS.
    """
    smallest = overhead + MIN_CHUNK_PAYLOAD
    if error_rate <= 0 or largest <= smallest:
        return max(largest, smallest)
    sizes = np.arange(smallest, largest + 1, dtype=float)
    good = np.exp(sizes * math.log1p(-min(error_rate, 0.5)))
    efficiency = good / (1 + waste * (1 - good)) * (sizes - overhead - sizes // 254) / sizes
    return int(sizes[int(np.argmax(efficiency))])


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


class PrinterLink:
    """One print job over one port (stateful: sequence numbers, window, timers), so a class."""

    def __init__(self, connector, job: JobSpec, get_layer: LayerSource, *, timing: LinkTiming = LinkTiming(),
                 rate_bytes_s: float | None = None, max_payload: int = 1024, encodings: int = P.ALL_ENCODINGS,
                 features: int = P.ALL_FEATURES, log: PrintLog | None = None,
                 on_progress: Callable[[Progress], None] | None = None, session_seed: int | None = None):
        if job.layer_count < 1:
            raise InputError("the job has no layers")
        self.connector, self.job, self.get_layer = connector, job, get_layer
        self.name = connector.name
        self.timing = timing
        self.rate = rate_bytes_s
        self.max_payload = min(max_payload, P.MAX_PAYLOAD_LIMIT)
        self.encodings = encodings | (1 << P.ENC_RAW)
        self.features = features
        self.log = log or PrintLog(None)
        self.on_progress = on_progress
        self._session_rng = np.random.default_rng(session_seed)
        self.port = None
        self.session = 0
        self.boot_id: int | None = None
        self.hello: P.HelloAck | None = None
        self.counters = _Counters()
        self.last_completed = -1
        self.last_queued = -1
        self.state = P.STATE_IDLE
        self.first_layer = 0
        self._splitter = P.FrameSplitter()
        self._frames: deque[_Out] = deque()
        self._send_idx = 0
        self._next_seq = 0
        self._credit = 0
        self._window = 1
        self._sack = False
        self._negotiated = 1 << P.ENC_RAW
        self._link_payload = 64
        self._generator: Iterator | None = None
        self._generator_done = False
        self._wire_busy = 0.0
        self._last_rx = 0.0
        self._stuck = 0
        self._backoff = 1
        self._await_resend = False
        self._tag = 0
        self._err_events = 0.0
        self._err_bytes = 0.0
        self._err_frames = 0.0
        self._budget: int | None = None
        self._budget_age = 0
        self._started = 0.0
        self._done_reported = -1

    # -- public ------------------------------------------------------------------------

    def run(self, from_layer: int | None = None) -> PrintResult:
        """Print the job (from ``from_layer`` or wherever the controller's copy of this job stands)."""
        self._started = time.monotonic()
        self.log.write("start", port=self.name, job_id=self.job.job_id, layers=self.job.layer_count,
                       channels=self.job.channels, width=self.job.width, height=self.job.height,
                       from_layer=from_layer)
        try:
            self._open()
            ack = self._handshake(time.monotonic() + self.timing.hello_timeout_s, first=True)
            start = self._first_layer(ack, from_layer)
            self.first_layer = start
            self._restart_stream(start)
            self.log.write("connected", boot_id=ack.boot_id, controller_state=P.STATE_NAMES.get(ack.state),
                           first_layer=start, encodings=self._negotiated, window=self._window,
                           rx_buffer=ack.rx_buffer, sack=self._sack)
            self._pump()
        except KeyboardInterrupt:
            self.abort()
            self.log.write("interrupted", last_completed=self.last_completed)
            raise PrintInterrupted(f"interrupted: ABORT sent to the controller on {self.name} "
                                   f"(last completed layer {self.last_completed})") from None
        except _LinkLost as lost:
            self.log.write("error", message=str(lost), kind="LinkDeadError", last_completed=self.last_completed)
            raise LinkDeadError(f"{self.name}: the link failed while connecting ({lost})") from None
        except Exception as err:
            self.log.write("error", message=str(err), kind=type(err).__name__, last_completed=self.last_completed)
            raise
        finally:
            self._close()
        result = self.result()
        self.log.write("done", **{k: v for k, v in result.__dict__.items()})
        return result

    def result(self) -> PrintResult:
        """Counters so far."""
        c = self.counters
        return PrintResult(self.first_layer, self.last_completed, max(0, self.last_completed - self.first_layer + 1),
                           c.bytes_sent, c.payload_bytes, c.raw_bytes, c.frames_sent, c.retransmitted, c.timeouts,
                           c.naks, c.reconnects, time.monotonic() - self._started, self.boot_id or 0, c.skipped,
                           self._sack)

    def abort(self) -> bool:
        """Send ABORT (out of band) until the controller reports it; True when confirmed."""
        return self._out_of_band(P.Abort(), P.STATE_ABORTED)

    def pause(self) -> bool:
        """Send PAUSE (out of band) until the controller reports it; True when confirmed."""
        return self._out_of_band(P.Pause(), P.STATE_PAUSED)

    # -- connection --------------------------------------------------------------------

    def _open(self) -> None:
        """Open the port and reset the frame splitter and the silence timer."""
        self.port = self.connector.open()
        self._splitter = P.FrameSplitter()
        self._last_rx = time.monotonic()

    def _close(self) -> None:
        """Close the port, ignoring errors of a port already broken."""
        if self.port is not None:
            try:
                self.port.close()
            except Exception:  # noqa: BLE001 - closing a broken port must not hide the real error
                pass
            self.port = None

    def _write(self, data: bytes) -> None:
        """Write bytes; a failing port becomes _LinkLost (reconnect)."""
        import serial

        try:
            self.port.write(data)
        except (serial.SerialException, OSError) as err:
            raise _LinkLost(str(err)) from err

    def _waiting(self) -> int:
        """Bytes ready to read (raises _LinkLost when the port has failed)."""
        import serial

        try:
            return self.port.in_waiting
        except (serial.SerialException, OSError) as err:
            raise _LinkLost(str(err)) from err

    def _read_frames(self) -> list[P.Frame]:
        """Valid frames among the bytes waiting now (invalid ones are dropped; the sender retransmits)."""
        import serial

        try:
            waiting = self.port.in_waiting
            data = self.port.read(max(1, waiting))
        except (serial.SerialException, OSError) as err:
            raise _LinkLost(str(err)) from err
        if not data:
            return []
        frames = []
        for item in self._splitter.feed(data):
            if isinstance(item, ProtocolError):
                continue
            frames.append(item)
        if frames:
            self._last_rx = time.monotonic()
        return frames

    def _handshake(self, deadline: float, first: bool) -> P.HelloAck:
        """HELLO until HELLO_ACK (new session); raise on silence, echo or another protocol version."""
        self.session = int(self._session_rng.integers(1, 1 << 16))
        hello = P.encode_frame(P.message_frame(P.Hello(P.PROTOCOL_VERSION, self.max_payload, self.encodings,
                                                       self.features), self.session))
        next_hello = 0.0
        while True:
            now = time.monotonic()
            if now >= deadline:
                what = "no controller answered" if first else "the controller stopped answering"
                raise LinkDeadError(f"{self.name}: {what} (no HELLO_ACK within "
                                    f"{self.timing.hello_timeout_s if first else self.timing.reconnect_s:g} s); "
                                    "check the port, cable, power and baud rate")
            if now >= next_hello:
                self._write(hello)
                next_hello = now + self.timing.hello_interval_s
            for frame in self._read_frames():
                if frame.type == P.Hello.TYPE:
                    raise IncompatibleControllerError(
                        f"{self.name}: received our own HELLO back: the port echoes (a loopback?), no controller")
                if frame.type != P.HelloAck.TYPE:
                    continue
                if frame.version != P.PROTOCOL_VERSION:
                    raise IncompatibleControllerError(
                        f"{self.name}: the controller speaks protocol version {frame.version}, heoslice speaks "
                        f"version {P.PROTOCOL_VERSION}; update the controller firmware or heoslice")
                if frame.session != self.session:
                    continue
                try:
                    ack = P.unpack_message(frame.type, frame.payload)
                except ProtocolError:
                    continue
                self._accept_hello(ack)
                return ack

    def _accept_hello(self, ack: P.HelloAck) -> None:
        """Take the controller's capabilities; check the job fits and the boot id is the one we started with."""
        job = self.job
        if self.boot_id is None:
            if job.channels > ack.channels or job.width > ack.max_width or job.height > ack.max_height:
                raise IncompatibleControllerError(
                    f"{self.name}: the job ({job.channels} channel(s), {job.width} x {job.height} px) does not fit "
                    f"the printer ({ack.channels} channel(s), at most {ack.max_width} x {ack.max_height} px)")
            self.boot_id = ack.boot_id
        elif ack.boot_id != self.boot_id:
            self._reset_detected(ack.boot_id, ack.job_id, ack.last_completed)
        self.hello = ack
        self._negotiated = (ack.encodings & self.encodings) | (1 << P.ENC_RAW)
        self._sack = bool(ack.features & self.features & P.FEATURE_SACK)
        self._link_payload = max(MIN_CHUNK_PAYLOAD + CHUNK_HEADER, min(self.max_payload, ack.max_payload))
        self._budget = None
        self._window = max(1, min(ack.window, P.SACK_SPAN if self._sack else 0x7FFF))
        self._credit = ack.rx_buffer
        self.state = ack.state
        self._note_progress(ack.last_queued, ack.last_completed)
        if ack.state == P.STATE_ERROR and ack.job_id == job.job_id:
            raise ControllerFaultError(f"{self.name}: the controller is in an error state "
                                       f"(after layer {ack.last_completed}); fix the printer and reset it")

    def _reset_detected(self, boot_id: int, job_id: int, last_completed: int) -> None:
        """Raise ControllerResetError naming the layer to resume from."""
        done = last_completed if job_id == self.job.job_id else self.last_completed
        raise ControllerResetError(
            f"{self.name}: the controller was reset during the print (boot id {self.boot_id:08x} -> {boot_id:08x}); "
            f"layers up to {done} were printed: check the part, then rerun with --from-layer {done + 1}",
            next_layer=done + 1)

    def _first_layer(self, ack: P.HelloAck, from_layer: int | None) -> int:
        """Where this run starts: --from-layer, the controller's resume point for this job, or 0."""
        job = self.job
        if from_layer is not None:
            _check_from_layer(job, from_layer)
            return from_layer
        if ack.job_id == job.job_id and ack.state in (P.STATE_RECEIVING, P.STATE_PAUSED):
            self.log.write("resume", layer=ack.last_queued + 1, controller_state=P.STATE_NAMES[ack.state])
            if ack.state == P.STATE_PAUSED:
                self._out_of_band(P.Resume(), P.STATE_RECEIVING)
            return ack.last_queued + 1
        if ack.job_id == job.job_id and ack.state == P.STATE_IDLE and 0 <= ack.last_completed < job.layer_count - 1:
            raise ControllerResetError(
                f"{self.name}: the controller was reset during an earlier print of this job after layer "
                f"{ack.last_completed}; check the part, then rerun with --from-layer {ack.last_completed + 1} "
                "(or --from-layer 0 to start over)", next_layer=ack.last_completed + 1)
        return 0

    def _reconnect(self, reason: str) -> None:
        """Reopen the port and say HELLO until the controller answers; resume with the same boot id."""
        self.counters.reconnects += 1
        self.log.write("reconnect", reason=reason, last_completed=self.last_completed)
        deadline = time.monotonic() + self.timing.reconnect_s
        while True:
            self._close()
            try:
                self._open()
                ack = self._handshake(deadline, first=False)
                break
            except (PortError, _LinkLost):
                if time.monotonic() >= deadline:
                    raise LinkDeadError(
                        f"{self.name}: link lost ({reason}) and the controller could not be reached again within "
                        f"{self.timing.reconnect_s:g} s (last completed layer {self.last_completed}); check cable "
                        "and power, then rerun the same command to resume") from None
                time.sleep(0.05)
        if ack.job_id == self.job.job_id and ack.state in (P.STATE_RECEIVING, P.STATE_PAUSED):
            resume = ack.last_queued + 1
            if ack.state == P.STATE_PAUSED:
                self._out_of_band(P.Resume(), P.STATE_RECEIVING)
        elif ack.job_id == self.job.job_id and ack.state == P.STATE_DONE:
            resume = self.job.layer_count
        else:
            resume = self.first_layer
        self.log.write("resume", layer=resume, boot_id=ack.boot_id)
        self._restart_stream(resume)

    def _out_of_band(self, message: P.Message, wanted_state: int) -> bool:
        """Send an out-of-band message until a STATUS shows ``wanted_state`` (or the wait ends)."""
        if self.port is None or not self.session:
            return False
        wire = P.encode_frame(P.message_frame(message, self.session))
        deadline = time.monotonic() + self.timing.abort_wait_s
        next_send = 0.0
        try:
            while time.monotonic() < deadline:
                if time.monotonic() >= next_send:
                    self._write(wire)
                    next_send = time.monotonic() + self.timing.abort_wait_s / 4
                for frame in self._read_frames():
                    if frame.type == P.Status.TYPE and frame.session == self.session:
                        try:
                            status = P.unpack_message(frame.type, frame.payload)
                        except ProtocolError:
                            continue
                        if status.state == wanted_state:
                            self.state = status.state
                            return True
        except _LinkLost:
            return False
        return False

    # -- the data stream ---------------------------------------------------------------

    def _restart_stream(self, start: int) -> None:
        """Begin a fresh data stream (seq 0) at layer ``start``."""
        self._frames.clear()
        self._send_idx = 0
        self._next_seq = 0
        self._await_resend = False
        self._stuck = 0
        self._backoff = 1
        self._generator = self._messages(start)
        self._generator_done = start >= self.job.layer_count and self.last_completed >= self.job.layer_count - 1

    def _messages(self, start: int) -> Iterator[tuple[P.Message, int, int]]:
        """(message, layer, raw bytes) of the data stream from layer ``start``; chunk sizes follow the link."""
        job = self.job
        yield P.JobBegin(job.job_id, start, job.layer_count, job.channels, job.width, job.height), -1, 0
        for index in range(start, job.layer_count):
            channels = list(self.get_layer(index))
            if len(channels) != job.channels or any(len(c) != job.channel_bytes for c in channels):
                raise InputError(f"layer {index}: expected {job.channels} channel(s) of {job.channel_bytes} bytes")
            yield P.LayerBegin(index, job.channels, job.channel_bytes, P.crc32(b"".join(channels))), index, 0
            for number, data in enumerate(channels):
                offset = 0
                while offset < len(data):
                    chunk, used = self._make_chunk(index, number, data, offset)
                    yield chunk, index, used
                    offset += used
            yield P.LayerEnd(index), index, 0
            yield P.Execute(index), index, 0
        yield P.JobEnd(job.job_id), job.layer_count - 1, 0

    def _chunk_budget(self) -> int:
        """Payload bytes per data frame now: the negotiated maximum, shrunk while bytes are being corrupted.

        The byte error rate is estimated from retransmission rounds per byte sent (with the prior
        of one in ``ERROR_PRIOR_BYTES``) as e = -ln(1 - p) / L, p the rounds per frame of mean
        size L; the frame size is then chosen by :func:`optimal_frame_bytes`. Re-estimated
        every 32 chunks and after every retransmission round.
        """
        self._budget_age += 1
        if self._budget is None or self._budget_age >= 32:
            per_byte = (self._err_events + 1) / (self._err_bytes + ERROR_PRIOR_BYTES)
            mean = self._err_bytes / self._err_frames if self._err_frames else 1.0
            rate = -math.log1p(-min(per_byte * mean, 0.5)) / mean
            frame = optimal_frame_bytes(rate, P.WIRE_OVERHEAD, P.wire_size(self._link_payload),
                                        waste=0.0 if self._sack else 1.0)
            self._budget = max(MIN_CHUNK_PAYLOAD, frame - P.WIRE_OVERHEAD - frame // 254)
            self._budget_age = 0
        return self._budget

    def _make_chunk(self, layer: int, channel: int, data: bytes, offset: int) -> tuple[P.Message, int]:
        """The next DATA or CHUNK from ``offset`` within the current frame budget."""
        return next_chunk(layer, channel, data, offset, min(self._chunk_budget(), self._link_payload),
                          self._negotiated)

    def _next_frame(self) -> _Out | None:
        """The next frame to transmit: a rewound one, or a new one from the message generator."""
        if self._send_idx < len(self._frames):
            return self._frames[self._send_idx]
        if self._generator_done:
            return None
        try:
            message, layer, raw = next(self._generator)
        except StopIteration:
            self._generator_done = True
            return None
        kind, payload = P.pack_message(message)
        out = _Out(self._next_seq, kind, payload, len(payload) + P.FRAME_OVERHEAD, layer, len(payload), raw)
        self._next_seq = (self._next_seq + 1) % P.SEQ_MODULUS
        self._frames.append(out)
        return out

    def _inflight(self) -> int:
        """Credit used: costs of the frames sent in this pass that the controller does not report held."""
        return sum(out.cost for out in itertools.islice(self._frames, self._send_idx) if not out.held)

    def _try_send(self, now: float) -> float | None:
        """Transmit frames the window, credit and pacing allow; return when pacing permits the next one.

        A frame the controller reports held (SACK) is passed over, not resent.
        """
        while True:
            out = self._next_frame()
            if out is None or self._send_idx >= self._window:
                return None
            if out.held:
                self._send_idx += 1
                self.counters.skipped += 1
                continue
            if self._inflight() + out.cost > self._credit:
                return None
            byte_time = 1.0 / self.rate if self.rate else 0.0
            lead = self.timing.poll_s
            if self.rate and self._wire_busy - now > lead:
                return self._wire_busy - lead
            self._tag = (self._tag + 1) & 0xFFFF
            out.tag = self._tag
            wire = P.encode_frame(P.Frame(out.kind, self.session, out.seq, out.tag, out.body))
            self._write(wire)
            self._wire_busy = max(self._wire_busy, now) + len(wire) * byte_time
            out.wire_end = self._wire_busy
            c = self.counters
            c.bytes_sent += len(wire)
            c.frames_sent += 1
            c.layer_bytes[out.layer] = c.layer_bytes.get(out.layer, 0) + len(wire)
            if out.sends:
                c.retransmitted += 1
                c.layer_retries[out.layer] = c.layer_retries.get(out.layer, 0) + 1
            else:
                c.payload_bytes += out.payload
                c.raw_bytes += out.raw
            self._err_bytes += len(wire)
            self._err_frames += 1
            if self._send_idx == 0:
                self._await_resend = False
            out.sends += 1
            self._send_idx += 1

    def _on_ack(self, ack_seq: int, credit: int, held: int | None = None) -> None:
        """Cumulative acknowledgement of every frame before ``ack_seq``, with fresh credit.

        ``held`` (ACK and NAK, with SACK): bit i tells that the controller holds seq ack_seq + 1 + i.
        """
        progressed = False
        while self._frames and P.seq_diff(ack_seq, self._frames[0].seq) > 0:
            self._frames.popleft()
            if self._send_idx > 0:
                self._send_idx -= 1
            progressed = True
        if progressed:
            self._stuck = 0
            self._backoff = 1
        if self._frames and P.seq_diff(ack_seq, self._frames[0].seq) == 0:
            self._frames[0].held = False
            if held is not None and self._sack:
                for out in itertools.islice(self._frames, 1, P.SACK_SPAN + 1):
                    out.held = bool(held >> (P.seq_diff(out.seq, ack_seq) - 1) & 1)
        if not self._frames or P.seq_diff(ack_seq, self._frames[0].seq) == 0 or progressed:
            self._credit = credit

    def _go_back(self, reason: str) -> None:
        """Go-back-N: retransmit every unacknowledged frame not reported held; pause after too many rounds."""
        self._send_idx = 0
        self._await_resend = True
        self._stuck += 1
        self._err_events += 1
        self._budget = None
        if self._err_bytes > 1 << 18:
            self._err_bytes /= 2
            self._err_events /= 2
            self._err_frames /= 2
        if self._stuck >= self.timing.retry_limit:
            head = self._frames[0] if self._frames else None
            paused = self.pause()
            self.log.write("retry-limit", seq=head.seq if head else None, layer=head.layer if head else None,
                           reason=reason, paused=paused)
            raise RetryLimitError(
                f"{self.name}: no progress after {self.timing.retry_limit} retransmissions "
                f"(layer {head.layer if head else '?'}, last: {reason}); the job is "
                f"{'paused' if paused else 'stopped'} on the controller after layer {self.last_completed}; "
                "check the link, then rerun the same command to resume")

    def _on_nak(self, expected: int, nak: P.Nak) -> None:
        """Go back to ``expected`` unless this NAK predates the latest transmission of that frame.

        Every data frame carries a transmission tag (header.ack, incremented per send);
        the NAK echoes the tag of the frame that provoked it (as TCP's timestamp echo
        does). A tag older than the resent frame's own tag belongs to the flight already
        rewound, so it is ignored.
        """
        self.counters.naks += 1
        if not self._frames or P.seq_diff(expected, self._frames[0].seq) != 0 or self._await_resend:
            return
        if P.seq_diff(nak.tag, self._frames[0].tag) < 0:
            return
        self._go_back(f"NAK ({nak.reason})")

    def _note_progress(self, last_queued: int, last_completed: int) -> None:
        """Log each newly executed layer and report progress."""
        self.last_queued = max(self.last_queued, last_queued)
        if last_completed <= self.last_completed:
            return
        for layer in range(max(self.last_completed + 1, self.first_layer), last_completed + 1):
            c = self.counters
            self.log.write("layer", layer=layer, bytes=c.layer_bytes.pop(layer, 0),
                           retries=c.layer_retries.pop(layer, 0),
                           status={"state": P.STATE_NAMES.get(self.state, str(self.state)),
                                   "last_completed": last_completed, "credit": self._credit})
        self.last_completed = last_completed
        if self.on_progress is not None:
            self.on_progress(Progress(last_completed, last_completed - self.first_layer + 1,
                                      self.job.layer_count - self.first_layer, self.counters.bytes_sent,
                                      time.monotonic() - self._started))

    def _on_status(self, frame: P.Frame, status: P.Status) -> None:
        """React to STATUS: reset, error or abort stop the print; otherwise it acknowledges like an ACK."""
        if self.boot_id is not None and status.boot_id != self.boot_id:
            self._reset_detected(status.boot_id, status.job_id, status.last_completed)
        if frame.session != self.session:
            return
        self.state = status.state
        if status.job_id == self.job.job_id:
            self._note_progress(status.last_queued, status.last_completed)
        if status.state == P.STATE_ERROR:
            raise ControllerFaultError(
                f"{self.name}: the controller reports {P.ERROR_NAMES.get(status.error, f'error {status.error}')} "
                f"at layer {status.error_layer}; the job is stopped after layer {status.last_completed} "
                f"(fix the printer, then rerun with --from-layer {status.last_completed + 1})")
        if status.state == P.STATE_ABORTED:
            raise ControllerFaultError(f"{self.name}: the controller aborted the job after layer "
                                       f"{status.last_completed}")
        self._on_ack(frame.ack, status.credit)

    def _dispatch(self, frame: P.Frame) -> None:
        """Route one frame from the controller."""
        if frame.version != P.PROTOCOL_VERSION:
            return
        try:
            message = P.unpack_message(frame.type, frame.payload)
        except ProtocolError:
            return
        if isinstance(message, P.Status):
            self._on_status(frame, message)
            return
        if frame.session != self.session:
            return
        if isinstance(message, P.Ack):
            self._on_ack(frame.ack, message.credit, message.held)
            self._note_progress(message.last_queued, message.last_completed)
        elif isinstance(message, P.Nak):
            self._on_ack(frame.ack, message.credit, message.held)
            self._on_nak(frame.ack, message)

    def _finished(self) -> bool:
        """True when every frame is acknowledged and the last layer executed."""
        return self._generator_done and not self._frames and self.last_completed >= self.job.layer_count - 1

    def _pump(self) -> None:
        """The main loop: send, read, time out, until the last layer is executed."""
        timing = self.timing
        while not self._finished():
            try:
                now = time.monotonic()
                wait_until = self._try_send(now)
                for frame in self._read_frames():
                    self._dispatch(frame)
                now = time.monotonic()
                if self._send_idx > 0:
                    head = self._frames[0]
                    if now > head.wire_end + timing.ack_timeout_s * self._backoff:
                        self.counters.timeouts += 1
                        self._backoff = min(self._backoff * 2, timing.max_backoff)
                        self._go_back("timeout")
                if now - self._last_rx > timing.silence_s:
                    raise _LinkLost(f"no frame for {timing.silence_s:g} s")
                if wait_until is not None and wait_until > now and not self._waiting():
                    time.sleep(min(wait_until - now, timing.poll_s))
            except _LinkLost as lost:
                self._reconnect(str(lost))


def print_job(port: str, job: JobSpec, get_layer: LayerSource, *, baud: int = 115200,
              from_layer: int | None = None, timing: LinkTiming = LinkTiming(), log_path: Path | None = None,
              on_progress: Callable[[Progress], None] | None = None, connector=None,
              max_payload: int = 1024, encodings: int = P.ALL_ENCODINGS,
              features: int = P.ALL_FEATURES) -> PrintResult:
    """Print ``job`` on ``port`` (device path, pyserial URL or ``sim://``); raise a PrinterError subclass on failure."""
    own = connector is None
    connector = connector or connector_for(port, baud)
    rate = connector.baud / 10.0 if getattr(connector, "baud", None) else None
    log = PrintLog(log_path)
    try:
        link = PrinterLink(connector, job, get_layer, timing=timing, rate_bytes_s=rate, max_payload=max_payload,
                           encodings=encodings, features=features, log=log, on_progress=on_progress)
        return link.run(from_layer)
    finally:
        log.close()
        if own:
            connector.close()


def _check_from_layer(job: JobSpec, from_layer: int) -> None:
    """--from-layer must name a layer of the stack (the same rule for a print and a dry run)."""
    if not 0 <= from_layer < job.layer_count:
        raise InputError(f"--from-layer {from_layer} is outside the stack's layers 0..{job.layer_count - 1}")


def plan_transfer(job: JobSpec, get_layer: LayerSource, *, baud: int = 115200, max_payload: int = 1024,
            encodings: int = P.ALL_ENCODINGS, from_layer: int = 0) -> dict:
    """Encode every frame of the job without a port: frames, wire bytes and the time at ``baud`` (8N1), s."""
    _check_from_layer(job, from_layer)
    frames = wire = raw = 0
    for index in range(from_layer, job.layer_count):
        channels = list(get_layer(index))
        frames += 3
        wire += 3 * P.wire_size(13)
        for number, data in enumerate(channels):
            raw += len(data)
            offset = 0
            while offset < len(data):
                message, span = next_chunk(index, number, data, offset, max_payload, encodings)
                frames += 1
                wire += P.wire_size(len(P.pack_message(message)[1]))
                offset += span
    return {"layers": job.layer_count - from_layer, "channels": job.channels, "raw_bytes": raw,
            "frames": frames, "wire_bytes": wire, "seconds_at_baud": wire * 10.0 / baud}


def job_summary(job: JobSpec) -> str:
    """One line describing a job."""
    return (f"{job.layer_count} layers, {job.channels} channel(s) of {job.width} x {job.height} px "
            f"({job.channel_bytes} bytes each), job id {job.job_id:08x}")


__all__ = ["JobSpec", "LinkTiming", "Progress", "PrintResult", "PrinterLink", "PrintLog", "print_job", "plan_transfer",
           "stack_job", "synthetic_job", "random_job", "pack_mask", "connector_for", "default_log_path",
           "SerialConnector", "SimConnector", "optimal_frame_bytes", "next_chunk"]
