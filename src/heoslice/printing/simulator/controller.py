"""A simulated printer controller speaking the protocol, with realistic pacing and seeded faults.

The simulator models what the host cannot see on real hardware: a link of ``baud``
bits/s (10 bits per byte, host -> controller direction paced), a bounded receive
buffer whose free space is the credit it grants, a print queue and a head that
takes ``layer_time_s`` per layer. ``time_scale`` multiplies both modelled durations
so tests run fast. Faults (corrupted, dropped and duplicated bytes and frames, lost
acks, delays, a reset mid-layer, a disconnect, a dead link, a persistent hardware
fault, another protocol version) are drawn from a seeded generator (:mod:`.faults`).

Every executed layer is recorded in :attr:`SimController.executed` (job, index, CRC of
the data printed, boot id) so tests can check exactly-once, in-order execution.
The controller runs one thread over a byte :class:`~.transports.Transport`.
"""

from __future__ import annotations

import secrets
import threading
import time
from collections.abc import Callable
from collections import deque

from heoslice.errors import ProtocolError
from heoslice.printing import protocol as P
from heoslice.printing.simulator.assembly import LayerAssembly
from heoslice.printing.simulator.config import ExecutedLayer, FaultSpec, SimConfig
from heoslice.printing.simulator.faults import FaultInjector
from heoslice.printing.simulator.transports import Transport


#: A host whose session sent nothing for this long no longer holds the controller, s.
OWNER_LEASE_S = 3.0


class SimController:
    """The simulated controller: call :meth:`run` on a thread (or :meth:`start`), :meth:`stop` to end it.

    ``log`` (e.g. a stderr writer) receives one line per connection, job, executed layer, abort,
    pause, resume and reset; None keeps it quiet.
    """

    def __init__(self, config: SimConfig = SimConfig(), faults: FaultSpec = FaultSpec(),
                 log: Callable[[str], None] | None = None):
        self.config = config
        self.log = log
        self._inject = FaultInjector(faults, config.seed)
        self.executed: list[ExecutedLayer] = []
        self.stats = {"frames": 0, "bad_frames": 0, "duplicates": 0, "out_of_order": 0, "naks": 0,
                      "acks_lost": 0, "resets": 0, "disconnects": 0, "hellos": 0, "aborts": 0, "held": 0,
                      "held_dropped": 0}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._transport: Transport | None = None
        self._pending_transport: Transport | None = None
        self._thread: threading.Thread | None = None
        self.died_at: float | None = None  # monotonic time the dead-link fault struck
        self.boot_id = self._new_boot_id()
        # persisted across resets (as in non-volatile memory): the job, its run, size and last printed layer
        self.job_id = 0
        self.run_id = 0
        self.layer_count = 0
        self.job_name = b""
        self.last_completed = -1
        self._power_on()

    @property
    def faults(self) -> FaultSpec:
        """The faults injected from now on (another FaultSpec assigned keeps the generator and struck faults)."""
        return self._inject.spec

    @faults.setter
    def faults(self, spec: FaultSpec) -> None:
        self._inject.spec = spec

    def _say(self, text: str) -> None:
        """One line of the controller's log."""
        if self.log is not None:
            self.log(text)

    # -- lifecycle ---------------------------------------------------------------------

    def _new_boot_id(self) -> int:
        """A random non-zero 32-bit boot id, fresh at every start and reset (not from the fault seed)."""
        return secrets.randbelow((1 << 32) - 1) + 1

    def _power_on(self) -> None:
        """State lost on a reset."""
        self.session = 0
        self.host_id = 0  # HELLO host id of the current session
        self._heard = 0.0  # monotonic time of the latest frame of the job's run (its host's session)
        self._aborting = False  # ABORT came while a layer was on the head: confirm once it is done
        self._stop_reading = False
        self.sack = False  # selective acknowledgement negotiated in this session
        self.state = P.STATE_IDLE
        self.error = P.ERR_NONE
        self.error_layer = -1
        self.expected = 0
        self.job_active = False
        self.job_end = False
        self.next_execute = 0
        self.last_queued = self.last_completed
        self._rx: deque = deque()
        self._rx_used = 0
        self._held: dict[int, tuple[P.Message, int]] = {}  # seq -> (message, cost): kept after a gap (SACK)
        self._held_used = 0
        self._rx_layer = -1  # layer of the latest layer-bearing data message received (DATA's link fault)
        self._in_layer = -1  # layer of the latest LAYER_BEGIN taken in order (DATA's layer faults)
        self._advertised = self.config.rx_buffer
        self._layer: LayerAssembly | None = None
        self._queue: deque = deque()
        self._printing: tuple | None = None
        self._print_end = 0.0
        self._paused = False
        self._splitter = P.FrameSplitter(P.wire_size(self.config.max_payload) + 16)
        self._arrivals: deque = deque()
        self._wire_free = 0.0
        self._stall_until = 0.0
        self._dead = False
        self._last_tag = 0

    def attach(self, transport: Transport) -> None:
        """Connect a (new) transport; the running loop switches to it."""
        with self._lock:
            self._pending_transport = transport

    def start(self, transport: Transport | None = None) -> "SimController":
        """Run on a daemon thread (one: a controller already running goes on, as a powered board does)."""
        if transport is not None:
            self.attach(transport)
        if self._thread is not None and self._thread.is_alive():
            return self
        self._thread = threading.Thread(target=self.run, name="heoslice-sim", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """End :meth:`run` and close the transport."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)
        if self._transport is not None:
            self._transport.close()

    def executed_layers(self, job_id: int | None = None) -> list[int]:
        """Indices of executed layers in execution order (of one job when ``job_id`` is given)."""
        with self._lock:
            return [e.layer for e in self.executed if job_id is None or e.job_id == job_id]

    # -- the loop ----------------------------------------------------------------------

    def run(self) -> None:
        """Serve until :meth:`stop`: read, pace, process, print, report."""
        next_status = time.monotonic()
        while not self._stop.is_set():
            with self._lock:
                if self._pending_transport is not None:
                    self._transport = self._pending_transport
                    self._pending_transport = None
                    self._splitter = P.FrameSplitter(P.wire_size(self.config.max_payload) + 16)
                    self._arrivals.clear()
            transport = self._transport
            now = time.monotonic()
            if self._stop_reading and not self._dead:
                self._run_head(now)
                if now >= next_status:
                    self._send_status()
                    next_status = now + self.config.status_interval_s
                time.sleep(0.01)
                continue
            if transport is None or self._dead:
                time.sleep(0.01)
                continue
            wake = [next_status, now + 0.02]
            if self._arrivals:
                wake.append(max(self._arrivals[0][0], self._stall_until))
            if self._printing is not None:
                wake.append(self._print_end)
            try:
                data = transport.recv(max(0.0, min(wake) - now))
            except OSError:
                data = b""
            now = time.monotonic()
            if data:
                self._on_bytes(data, now)
            self._deliver(now)
            self._drain()
            self._run_head(time.monotonic())
            if time.monotonic() >= next_status:
                self._send_status()
                next_status = time.monotonic() + self.config.status_interval_s

    def _on_bytes(self, data: bytes, now: float) -> None:
        """Apply byte faults and give each delimited piece its modelled arrival time."""
        data = self._inject.inbound(data)
        byte_time = self.config.byte_time_s
        start = 0
        while start < len(data):
            end = data.find(b"\x00", start)
            end = len(data) if end < 0 else end + 1
            piece = data[start:end]
            self._wire_free = max(self._wire_free, now) + len(piece) * byte_time
            self._arrivals.append((self._wire_free, piece))
            start = end

    def _deliver(self, now: float) -> None:
        """Hand pieces whose modelled arrival time has passed to the frame splitter."""
        while self._arrivals and self._arrivals[0][0] <= now and now >= self._stall_until:
            _, piece = self._arrivals.popleft()
            for item in self._splitter.feed(piece):
                if isinstance(item, ProtocolError):
                    self.stats["bad_frames"] += 1
                    if self.session and self.state != P.STATE_ERROR:
                        self.stats["naks"] += 1
                        self._send(P.Nak((self._last_tag + 1) & 0xFFFF, self._credit(), P.NAK_BAD_FRAME,
                                         self._held_mask()))
                    continue
                self._on_frame(item, time.monotonic())
                if self._dead or now < self._stall_until:
                    break

    def _send(self, message: P.Message, version: int | None = None) -> None:
        """Encode and write one frame (with byte errors applied on the way out); header.ack = next expected seq."""
        if self._transport is None or self._dead:
            return
        frame = P.message_frame(message, self.session, 0, self.expected,
                                self.config.version if version is None else version)
        self._transport.send(self._inject.outbound(P.encode_frame(frame)))

    def _credit(self) -> int:
        """Free receive-buffer bytes (frames held after a gap occupy it too): the credit granted to the host."""
        return self.config.rx_buffer - self._rx_used - self._held_used

    def _held_mask(self) -> int:
        """ACK/NAK ``held``: bit i set when the frame with seq expected + 1 + i is held (SACK)."""
        mask = 0
        for seq in self._held:
            mask |= 1 << (P.seq_diff(seq, self.expected) - 1)
        return mask

    def _drop_received(self) -> None:
        """Forget every frame received but not applied, and the layer being assembled."""
        self._rx.clear()
        self._rx_used = 0
        self._held.clear()
        self._held_used = 0
        self._layer = None

    def _send_ack(self) -> None:
        """Cumulative ACK with the current credit, progress and held frames."""
        self._advertised = self._credit()
        self._send(P.Ack(self._credit(), self.job_id, self.run_id, self.last_queued, self._claimed(),
                         self._held_mask()))

    def _claimed(self) -> int:
        """The last_completed reported: the truth, unless the claim_completed fault makes it lie."""
        return self._inject.claimed_completed(self.last_completed)

    def _send_status(self) -> None:
        """STATUS: boot id, state, progress, credit, error."""
        self._advertised = self._credit()
        self._send(P.Status(self.boot_id, self.state, self.job_id, self.run_id, self._claimed(), self.last_queued,
                            self._credit(), self.error, self.error_layer))

    # -- frames ------------------------------------------------------------------------

    def _on_frame(self, frame: P.Frame, now: float) -> None:
        """Apply frame-level faults (drop, delay, duplicate), then handle the frame."""
        self.stats["frames"] += 1
        fate = self._inject.frame_fate()
        if fate is None:
            return
        if fate.delayed:
            self._stall_until = now + self.faults.delay_s * self.config.time_scale
        for _ in range(fate.repeats):
            self._handle(frame)

    def _handle(self, frame: P.Frame) -> None:
        """Dispatch one frame: HELLO and STATUS_REQ always, the rest only in the current session."""
        if frame.type == P.Hello.TYPE:
            self._on_hello(frame)
            return
        if frame.version != self.config.version:
            return
        if self.session and frame.session == self.session and self.host_id == self.run_id:
            self._heard = time.monotonic()
        if frame.type == P.StatusRequest.TYPE:
            self._send_status()
            return
        if self.session == 0 or frame.session != self.session:
            return  # stale frame of an earlier connection, or nobody said HELLO since boot
        if frame.type in P.DATA_TYPES:
            self._on_data(frame)
        elif frame.type == P.Abort.TYPE:
            self._on_abort()
        elif frame.type == P.Pause.TYPE:
            self._say("pause")
            self._paused = True
            if self.state == P.STATE_RECEIVING:
                self.state = P.STATE_PAUSED
            self._send_status()
        elif frame.type == P.Resume.TYPE:
            self._say("resume")
            self._paused = False
            if self.state == P.STATE_PAUSED:
                self.state = P.STATE_RECEIVING
            self._send_status()

    def _on_abort(self) -> None:
        """ABORT: drop the queue and the stream; confirm (state aborted) once the head has stopped."""
        self.stats["aborts"] += 1
        self._queue.clear()
        self._drop_received()
        self.job_active = False
        if self.state == P.STATE_ERROR:
            self._send_status()
            return
        self._say(f"abort: job {self.job_id:08x} after layer {self.last_completed}"
                  + (f", layer {self._printing[0]} finishing on the head" if self._printing else ""))
        self._aborting = True
        self._confirm_abort()

    def _confirm_abort(self) -> None:
        """Enter state aborted once nothing is on the head; nothing is queued any more."""
        if self._aborting and self._printing is None:
            self._aborting = False
            self.state = P.STATE_ABORTED
            self.last_queued = self.last_completed
            self._send_status()

    def _busy_for(self, host_id: int) -> bool:
        """True when the host of the job in progress (its run) is live and another host says HELLO."""
        return (self.run_id != 0 and host_id != self.run_id
                and self.state == P.STATE_RECEIVING and time.monotonic() - self._heard < OWNER_LEASE_S)

    def _on_hello(self, frame: P.Frame) -> None:
        """Open the host's session (same version, not busy) and answer with HELLO_ACK in our own version."""
        self.stats["hellos"] += 1
        cfg = self.config
        features = flags = 0
        if frame.version == cfg.version:
            try:
                hello = P.unpack_message(frame.type, frame.payload)
            except ProtocolError:
                return
            if self._busy_for(hello.host_id):
                flags = P.HELLO_BUSY
                self._say(f"busy: refused host {hello.host_id:08x} (host {self.run_id:08x} is printing "
                          f"job {self.job_id:08x})")
            else:
                if hello.host_id != self.host_id or frame.session != self.session:
                    self._say(f"connection: session {frame.session:04x}, host {hello.host_id:08x}")
                self.session = frame.session
                self.host_id = hello.host_id
                if self.host_id == self.run_id:
                    self._heard = time.monotonic()
                self.expected = 0
                self._drop_received()
                features = hello.features & cfg.features
                self.sack = bool(features & P.FEATURE_SACK)
        reply = P.HelloAck(cfg.version, self.boot_id, self._credit(), cfg.window, cfg.max_payload,
                           cfg.encodings, cfg.channels, cfg.max_width, cfg.max_height, cfg.dpi_x, cfg.dpi_y,
                           self.job_id, self.run_id, self._claimed(), self.last_queued, self.layer_count,
                           self.state, features, flags, self.job_name)
        saved = self.session
        self.session = frame.session
        self._send(reply)
        self.session = saved

    def _on_data(self, frame: P.Frame) -> None:
        """The receiver: take the expected seq into the buffer (ACK), re-ACK duplicates, NAK gaps.

        Plain go-back-N discards a frame ahead of the expected one; with SACK it is held
        (within ``SACK_SPAN`` and the credit) and applied once the gap is filled; held
        frames farthest ahead are dropped again when the expected frame needs their room,
        so they can never block the gap. Every reply carries the held frames in ``held``.
        """
        if self.state == P.STATE_ERROR:
            return
        self._last_tag = frame.ack
        distance = P.seq_diff(frame.seq, self.expected)
        if distance < 0:
            self.stats["duplicates"] += 1
            self._send_ack()
            return
        cost = len(frame.payload) + P.FRAME_OVERHEAD
        if distance > 0:
            self.stats["out_of_order"] += 1
            if self.sack and distance <= min(P.SACK_SPAN, self.config.window) and frame.seq not in self._held \
                    and cost <= self._credit():
                message = self._receive(frame)
                if message is not None:
                    self._held[frame.seq] = (message, cost)
                    self._held_used += cost
                    self.stats["held"] += 1
            self.stats["naks"] += 1
            self._send(P.Nak(frame.ack, self._credit(), P.NAK_OUT_OF_ORDER, self._held_mask()))
            return
        while cost > self._credit() and self._held:
            _, dropped = self._held.pop(max(self._held, key=lambda seq: P.seq_diff(seq, self.expected)))
            self._held_used -= dropped
            self.stats["held_dropped"] += 1
        if cost > self._credit():
            self.stats["naks"] += 1
            self._send(P.Nak(frame.ack, self._credit(), P.NAK_NO_CREDIT, self._held_mask()))
            return
        message = self._receive(frame)
        if message is None:
            return
        session = self.session
        self._accept(message, cost)
        while self.session == session and self.expected in self._held and not self._dead:
            message, cost = self._held.pop(self.expected)
            self._held_used -= cost
            self._accept(message, cost)
        if self.session != session or self._dead:
            return
        if self._inject.ack_lost():
            self.stats["acks_lost"] += 1
        else:
            self._send_ack()

    def _receive(self, frame: P.Frame) -> P.Message | None:
        """The data message of a frame, or None when it is malformed (job error) or the link fault eats it."""
        try:
            message = P.unpack_message(frame.type, frame.payload)
        except ProtocolError:
            self._fail(P.ERR_BAD_JOB, -1)
            return None
        layer = getattr(message, "layer", None)
        if layer is not None:
            self._rx_layer = layer
        return None if self._inject.data_lost(message, self._rx_layer) else message

    def _accept(self, message: P.Message, cost: int) -> None:
        """Take the next in-order message into the receive buffer; strike the faults tied to its layer."""
        self.expected = (self.expected + 1) % P.SEQ_MODULUS
        self._rx.append((message, cost))
        self._rx_used += cost
        if isinstance(message, P.LayerBegin):
            self._in_layer = message.layer
        elif isinstance(message, P.Chunk):
            self._chunk_faults(message.layer)
        elif isinstance(message, P.Data):
            self._chunk_faults(self._in_layer)

    def _chunk_faults(self, layer: int) -> None:
        """Act on the fault that strikes while a layer is being received: reset, disconnect, dead link, stop
        reading (:meth:`.faults.FaultInjector.layer_fault`)."""
        fault = self._inject.layer_fault(layer)
        if fault == "reset":
            self._reset()
        elif fault == "disconnect":
            self.stats["disconnects"] += 1
            if self._transport is not None:
                self._transport.disconnect(self.faults.disconnect_s)
        elif fault == "dead":
            self._dead = True
            self.died_at = time.monotonic()
        elif fault == "stop-reading":
            self._stop_reading = True
            self.died_at = time.monotonic()

    def _reset(self) -> None:
        """Reboot: the layer on the head completes, everything else in memory is lost; new boot id."""
        self.stats["resets"] += 1
        if self._printing is not None:
            self._finish_layer()
        self.boot_id = self._new_boot_id()
        self._say(f"reset: new boot id {self.boot_id:08x}; job {self.job_id:08x} kept after layer "
                  f"{self.last_completed}")
        self._power_on()
        self._send_status()

    def _fail(self, error: int, layer: int) -> None:
        """Enter the error state (persistent until a reset) and report it."""
        self.state = P.STATE_ERROR
        self.error = error
        self.error_layer = layer
        self._queue.clear()
        self._send_status()

    # -- processing the receive buffer -------------------------------------------------

    def _drain(self) -> None:
        """Apply buffered data frames in order, stopping when the print queue is full."""
        while self._rx and self.state != P.STATE_ERROR:
            message, cost = self._rx[0]
            if isinstance(message, P.Execute) and message.layer >= self.next_execute \
                    and len(self._queue) >= self.config.print_queue:
                break
            self._rx.popleft()
            self._rx_used -= cost
            self._apply(message)
        if self._credit() - self._advertised >= max(self.config.rx_buffer // 4, 1):
            self._send_ack()

    def _apply(self, message: P.Message) -> None:
        """Apply one in-order data message to the job, the layer being assembled or the print queue."""
        if isinstance(message, P.JobBegin):
            self._begin_job(message)
        elif not self.job_active:
            return
        elif isinstance(message, P.LayerBegin):
            self._layer = None
            if message.layer >= self.next_execute and message.channels >= 1:
                self._layer = LayerAssembly.begin(message)
        elif isinstance(message, P.Chunk):
            layer = self._layer
            if layer is not None and message.layer == layer.index and not layer.write_chunk(message):
                self._fail(P.ERR_LAYER_CRC, message.layer)
        elif isinstance(message, P.Data):
            layer = self._layer
            if layer is not None and not layer.write_data(message):
                self._fail(P.ERR_LAYER_CRC, layer.index)
        elif isinstance(message, P.LayerEnd):
            layer = self._layer
            if layer is not None and message.layer == layer.index and not layer.finish():
                self._fail(P.ERR_LAYER_CRC, layer.index)
        elif isinstance(message, P.Execute):
            self._queue_layer(message.layer)
        elif isinstance(message, P.JobEnd):
            if not self.job_end:
                self._say(f"job {self.job_id:08x}: end received (layers up to {self.last_queued} queued)")
            self.job_end = True
            self._check_done()

    def _begin_job(self, message: P.JobBegin) -> None:
        """JOB_BEGIN: continue the active job at its next layer, or start it afresh at ``first_layer``."""
        cfg = self.config
        if message.channels > cfg.channels or message.width > cfg.max_width or message.height > cfg.max_height:
            self._fail(P.ERR_BAD_JOB, message.first_layer)
            return
        same = self.job_active and message.job_id == self.job_id and message.first_layer == self.next_execute
        self._say(f"job {message.job_id:08x}: {'continued' if same else 'begun'} at layer "
                  f"{message.first_layer} of {message.layer_count} by host {self.host_id:08x}")
        self.run_id = self.host_id
        self._heard = time.monotonic()
        if not same:
            self._queue.clear()
            self.job_id = message.job_id
            self.next_execute = message.first_layer
            self.last_queued = message.first_layer - 1
            self.last_completed = message.first_layer - 1
            self.layer_count = message.layer_count
            self.job_name = message.name[:P.JOB_NAME_LIMIT]
            self.job_active = True
            self.job_end = False
        self.state = P.STATE_PAUSED if self._paused else P.STATE_RECEIVING
        self._send_status()

    def _queue_layer(self, index: int) -> None:
        """EXECUTE: queue the verified layer once; a repeat is ignored, any other is error 2."""
        if index < self.next_execute:
            return  # already queued or printed: executed once only
        layer = self._layer
        if index != self.next_execute or layer is None or layer.index != index or not layer.complete:
            self._fail(P.ERR_OUT_OF_ORDER, index)
            return
        self._queue.append((layer.index, layer.crc_received))
        self.last_queued = layer.index
        self.next_execute = layer.index + 1
        self._layer = None

    # -- the head ----------------------------------------------------------------------

    def _run_head(self, now: float) -> None:
        """Finish the layer on the head when its time is up; start the next queued one unless paused or failed."""
        if self._printing is not None and now >= self._print_end:
            self._finish_layer()
            self._send_status()
            self._check_done()
        if self._printing is None and self._queue and not self._paused and self.state != P.STATE_ERROR:
            index, crc = self._queue[0]
            if self._inject.hardware_fault(index):
                self._fail(P.ERR_HARDWARE, index)
                return
            self._queue.popleft()
            self._printing = (index, crc)
            self._print_end = now + self.config.layer_time_s * self.config.time_scale

    def _finish_layer(self) -> None:
        """Record the layer on the head as executed."""
        index, crc = self._printing
        with self._lock:
            self.executed.append(ExecutedLayer(self.job_id, index, crc, self.boot_id, self.run_id))
        self.last_completed = index
        self._printing = None
        self._say(f"layer {index} executed (job {self.job_id:08x})")
        self._confirm_abort()

    def _check_done(self) -> None:
        """Report DONE once JOB_END came and the last layer is printed."""
        if self.job_active and self.job_end and not self._queue and self._printing is None \
                and self.last_completed == self.layer_count - 1:
            self.state = P.STATE_DONE
            self.job_active = False
            self._say(f"job {self.job_id:08x} done: {self.layer_count} layers")
            self._send_status()
