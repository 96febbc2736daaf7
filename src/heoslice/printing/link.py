"""The host side of ``heoslice print``: drive one job over a :class:`~heoslice.printing.session.Session`.

:class:`PrinterLink` feeds the job's data stream (:mod:`~heoslice.printing.stream`) through the send
window (:mod:`~heoslice.printing.window`), reads ACK / NAK / STATUS, logs each executed layer, and on a
lost link reconnects and resumes while the controller keeps its boot id. Protocol: ``docs/protocol.md``.
"""

from __future__ import annotations

import secrets
import signal
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from heoslice.errors import (ControllerBusyError, ControllerFaultError, ControllerResetError,
                             IncompatibleControllerError, InputError, LinkDeadError, PortError, PrintInterrupted, ProtocolError, RetryLimitError,
                             StackChangedError, UnfinishedJobError)
from heoslice.printing import protocol as P
from heoslice.printing.job import JobSpec, LayerSource, misfit
from heoslice.printing.log import PrintLog, last_run
from heoslice.printing.ports import Connector, connector_for
from heoslice.printing.resume import decide_start
from heoslice.printing.session import LinkLost, LinkTiming, Session
from heoslice.printing.stream import CHUNK_HEADER, job_messages
from heoslice.printing.window import MIN_CHUNK_PAYLOAD, FrameSizer, OutFrame, SendWindow


#: Without SACK, writes run ahead of the wire by at most this many mean error-free runs (see PrinterLink._lead_s).
LEAD_RUNS = 0.5


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
    resplits: int = 0  # new sessions opened to make unacknowledged frames again, smaller


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
    resplits: int = 0
    layer_bytes: dict = field(default_factory=dict)
    layer_retries: dict = field(default_factory=dict)

    def on_sent(self, out: OutFrame, wire_bytes: int, resent: bool) -> None:
        """Count one transmission of ``out``."""
        self.bytes_sent += wire_bytes
        self.frames_sent += 1
        self.layer_bytes[out.layer] = self.layer_bytes.get(out.layer, 0) + wire_bytes
        if resent:
            self.retransmitted += 1
            self.layer_retries[out.layer] = self.layer_retries.get(out.layer, 0) + 1
        else:
            self.payload_bytes += out.payload
            self.raw_bytes += out.raw


class PrinterLink:
    """One print run over one connector: the stream, the window, progress and reconnection (stateful, so a class).

    The run has its own random ``host_id`` (HELLO), kept across reconnects: the controller reports
    progress with the job and run it belongs to, and only this run's progress of this job is logged.
    """

    def __init__(self, connector: Connector, job: JobSpec, get_layer: LayerSource, *,
                 timing: LinkTiming = LinkTiming(), max_payload: int = 1024, encodings: int = P.ALL_ENCODINGS,
                 features: int = P.ALL_FEATURES, log: PrintLog | None = None,
                 on_progress: Callable[[Progress], None] | None = None, session_seed: int | None = None,
                 label: str = "this stack", name: str = ""):
        if job.layer_count < 1:
            raise InputError("the job has no layers")
        self.job, self.get_layer, self.label, self.job_name = job, get_layer, label, name
        self.name = connector.name
        self.timing = timing
        self.max_payload = min(max_payload, P.MAX_PAYLOAD_LIMIT)
        self.encodings = encodings | (1 << P.ENC_RAW)
        self.features = features
        self.host_id = secrets.randbelow((1 << 32) - 1) + 1
        self.session = Session(connector, timing, P.Hello(P.PROTOCOL_VERSION, self.max_payload, self.encodings,
                                                          features, self.host_id), session_seed)
        self.log = log or PrintLog(None)
        self.on_progress = on_progress
        self.window = SendWindow()
        self.sizer = FrameSizer()
        self.counters = _Counters()
        self.boot_id: int | None = None
        self.last_completed = -1
        self.last_queued = -1
        self.state = P.STATE_IDLE
        self.first_layer = 0
        self._queued_base = -1  # layers the controller already held queued for this job when this run began
        self._sent_execute = -1  # highest layer this run sent EXECUTE for
        self._last_advance = 0.0
        self._acked_at = 0.0  # start of the current flight, or its latest acknowledgement
        self._negotiated = 1 << P.ENC_RAW
        self._link_payload = MIN_CHUNK_PAYLOAD + CHUNK_HEADER
        self._generator: Iterator | None = None
        self._generator_done = False
        self._started = 0.0
        self._logged = None  # the print log's last run of this job before this one (log.last_run)

    # -- public ------------------------------------------------------------------------

    def run(self, from_layer: int | None = None, *, resume: bool = False, restart: bool = False) -> PrintResult:
        """Print the job: from layer 0, or as ``--from-layer`` / ``--resume`` / ``--restart`` say (resume.py)."""
        self._started = time.monotonic()
        self._logged = last_run(self.log.path, self.job.job_id)  # before this run's own start is logged
        self.log.write("start", port=self.name, job_id=f"{self.job.job_id:08x}", host_id=f"{self.host_id:08x}",
                       layers=self.job.layer_count, channels=self.job.channels, width=self.job.width,
                       height=self.job.height, from_layer=from_layer, resume=resume, restart=restart)
        try:
            self.session.open()
            ack = self.session.handshake(time.monotonic() + self.timing.hello_timeout_s, first=True)
            self._accept_hello(ack)
            self.first_layer = self._begin(ack, from_layer, resume, restart)
            self._restart_stream(self.first_layer)
            self.log.write("connected", boot_id=f"{ack.boot_id:08x}", controller_state=P.STATE_NAMES.get(ack.state),
                           first_layer=self.first_layer, encodings=self._negotiated, window=self.window.window,
                           rx_buffer=ack.rx_buffer, sack=self.window.sack,
                           baud=getattr(self.session.connector, "baud", None))
            self._pump()
        except KeyboardInterrupt as interrupt:
            raise self._interrupted(interrupt) from None
        except LinkLost as lost:
            self.log.write("error", message=str(lost), kind="LinkDeadError", last_completed=self.last_completed)
            raise LinkDeadError(f"{self.name}: the link failed while connecting ({lost})") from None
        except StackChangedError as err:
            aborted = self.abort()
            self.log.write("error", message=str(err), kind=type(err).__name__, last_completed=self.last_completed,
                           aborted=aborted)
            raise
        except Exception as err:
            self.log.write("error", message=str(err), kind=type(err).__name__, last_completed=self.last_completed)
            raise
        finally:
            self.session.close()
        result = self.result()
        self.log.write("done", **{**result.__dict__, "boot_id": f"{result.boot_id:08x}"})
        return result

    def result(self) -> PrintResult:
        """Counters so far."""
        c = self.counters
        return PrintResult(self.first_layer, self.last_completed, max(0, self.last_completed - self.first_layer + 1),
                           c.bytes_sent, c.payload_bytes, c.raw_bytes, c.frames_sent, c.retransmitted, c.timeouts,
                           c.naks, c.reconnects, time.monotonic() - self._started, self.boot_id or 0, c.skipped,
                           self.window.sack, c.resplits)

    def abort(self) -> bool:
        """Send ABORT (out of band) until the controller confirms the head stopped; True when confirmed."""
        status = self.session.out_of_band(P.Abort(), P.STATE_ABORTED, self.timing.abort_wait_s + 1.0)
        if status is None:
            return False
        self.state = status.state
        if self._own(status.job_id, status.run_id) and status.last_completed <= self.job.layer_count - 1:
            self.last_completed = max(self.last_completed, status.last_completed)
        return True

    def pause(self) -> bool:
        """Send PAUSE (out of band) until the controller reports it; True when confirmed."""
        return self._out_of_band(P.Pause(), P.STATE_PAUSED)

    def _out_of_band(self, message: P.Message, wanted_state: int) -> bool:
        """An out-of-band message confirmed by a STATUS in ``wanted_state``."""
        status = self.session.out_of_band(message, wanted_state)
        if status is None:
            return False
        self.state = status.state
        return True

    def _interrupted(self, interrupt: KeyboardInterrupt) -> PrintInterrupted:
        """ABORT, log ``interrupted`` and the one-line error naming the last layer the head really completed."""
        signum = getattr(interrupt, "signum", signal.SIGINT)
        what = signal.Signals(signum).name
        confirmed = self.abort()
        self.log.write("interrupted", signal=what, last_completed=self.last_completed, abort_confirmed=confirmed)
        done = (f"the head completed layers {self.first_layer}..{self.last_completed}"
                if self.last_completed >= self.first_layer else "no layer of this run was completed")
        return PrintInterrupted(
            f"interrupted ({what}): ABORT sent to the controller on {self.name}"
            f"{'' if confirmed else ' (not confirmed)'}; {done} (last completed layer {self.last_completed}); "
            "rerun with --resume to continue or --restart to start over", exit_code=128 + signum)

    # -- connection --------------------------------------------------------------------

    def _own(self, job_id: int, run_id: int) -> bool:
        """True when a progress report belongs to this job and this run."""
        return job_id == self.job.job_id and run_id == self.host_id

    def _accept_hello(self, ack: P.HelloAck) -> None:
        """Take the controller's capabilities; refuse a busy, unusable or reset controller, or a job too big."""
        job = self.job
        if ack.flags & P.HELLO_BUSY:
            theirs = ack.job_name.decode("utf-8", "replace")
            raise ControllerBusyError(
                f"{self.name}: the controller is busy: another host is printing job {ack.job_id:08x}"
                f"{f' ({theirs!r})' if theirs else ''} on it "
                f"(last completed layer {ack.last_completed}); nothing was changed; wait for that print to end")
        smallest_frame = MIN_CHUNK_PAYLOAD + P.FRAME_OVERHEAD
        if ack.window < 1 or ack.max_payload < MIN_CHUNK_PAYLOAD or ack.rx_buffer < smallest_frame:
            raise IncompatibleControllerError(
                f"{self.name}: the controller offers a window of {ack.window} frame(s), a {ack.rx_buffer}-byte "
                f"receive buffer and {ack.max_payload}-byte payloads: too little to send one data frame")
        if self.boot_id is None:
            problem = misfit(job, ack)
            if problem:
                raise IncompatibleControllerError(f"{self.name}: {problem}")
            self.boot_id = ack.boot_id
        elif ack.boot_id != self.boot_id:
            self._reset_detected(ack.boot_id, ack.job_id, ack.last_completed)
        self._negotiated = (ack.encodings & self.encodings) | (1 << P.ENC_RAW)
        sack = bool(ack.features & self.features & P.FEATURE_SACK)
        self._link_payload = max(MIN_CHUNK_PAYLOAD + CHUNK_HEADER, min(self.max_payload, ack.max_payload))
        self.sizer.invalidate()
        self.window.configure(ack.window, ack.rx_buffer, sack)
        self.state = ack.state
        self._last_advance = time.monotonic()
        if self._own(ack.job_id, ack.run_id):
            self._note_progress(ack.last_queued, ack.last_completed)
        if ack.state == P.STATE_ERROR and ack.job_id == job.job_id:
            raise ControllerFaultError(f"{self.name}: the controller is in an error state "
                                       f"(after layer {ack.last_completed}); fix the printer and reset it")

    def _reset_detected(self, boot_id: int, job_id: int, last_completed: int) -> None:
        """Raise ControllerResetError naming the layer to resume from."""
        done = last_completed if job_id == self.job.job_id and last_completed < self.job.layer_count \
            else self.last_completed
        if self.last_completed < done <= max(self._sent_execute, self._queued_base):  # executed, not yet logged
            self._note_progress(max(self.last_queued, done), done)
        raise ControllerResetError(
            f"{self.name}: the controller was reset during the print (boot id {self.boot_id:08x} -> {boot_id:08x}); "
            f"layers up to {done} were printed: check the part, then rerun with --from-layer {done + 1}",
            next_layer=done + 1)

    def _begin(self, ack: P.HelloAck, from_layer: int | None, resume: bool, restart: bool) -> int:
        """The first layer of this run (resume.decide_start), after ABORT / RESUME where the decision asks."""
        start = decide_start(ack, self.job, self.name, self.label, from_layer=from_layer, resume=resume,
                             restart=restart, logged=self._logged)
        if start.event:
            self.log.write(start.event, layer=start.layer, controller_job=f"{ack.job_id:08x}",
                           controller_state=P.STATE_NAMES.get(ack.state), last_completed=ack.last_completed)
        if start.abort_first and not self.abort():
            raise UnfinishedJobError(f"{self.name}: --restart: the controller did not confirm the ABORT of job "
                                     f"{ack.job_id:08x}; nothing was sent")
        if start.resume_paused:
            self._out_of_band(P.Resume(), P.STATE_RECEIVING)
        if start.event == "resume" and ack.job_id == self.job.job_id:
            self._queued_base = ack.last_queued
        self.last_completed = start.layer - 1
        self.last_queued = start.layer - 1
        return start.layer

    def _reconnect(self, reason: str) -> None:
        """Reopen the port and say HELLO until the controller answers; resume with the same boot id (budgeted)."""
        self.counters.reconnects += 1
        if self.counters.reconnects > self.timing.max_reconnects:
            raise LinkDeadError(f"{self.name}: the link was lost {self.counters.reconnects} times during this job "
                                f"(last: {reason}); giving up after layer {self.last_completed}: check the cable, "
                                "then rerun with --resume")
        self.log.write("reconnect", reason=reason, last_completed=self.last_completed)
        deadline = min(time.monotonic() + self.timing.reconnect_s, self._dead_by())
        since = self._heard()
        while True:
            self.session.close()
            try:
                self.session.open()
                ack = self.session.handshake(deadline, first=False, since=since)
                break
            except (PortError, LinkLost):
                if time.monotonic() >= deadline:
                    raise LinkDeadError(
                        f"{self.name}: link lost ({reason}) and the controller could not be reached again within "
                        f"{self.timing.reconnect_s:g} s (last completed layer {self.last_completed}); check cable "
                        "and power, then rerun with --resume") from None
                time.sleep(0.05)
        self._accept_hello(ack)
        self._continue_after(ack, "resume")

    def _heard(self) -> float:
        """When the controller last answered: its last frame, or with frames in flight their last acknowledgement
        (a controller that stopped reading still sends STATUS)."""
        heard = self.session.last_rx
        return min(heard, self._acked_at) if self.window.in_flight else heard

    def _dead_by(self) -> float:
        """When the link is dead unless the controller answers: ``silence_s + reconnect_s`` after it last did (the
        documented bound, whatever path the silence takes: timeouts, a re-split's HELLO, a reconnection)."""
        return self._heard() + self.timing.silence_s + self.timing.reconnect_s

    def _continue_after(self, ack: P.HelloAck, event: str) -> None:
        """Restart the stream after a new session: at this run's resume point, or its first layer if never begun."""
        if self._own(ack.job_id, ack.run_id) and ack.state in (P.STATE_RECEIVING, P.STATE_PAUSED):
            resume = ack.last_queued + 1
            if ack.state == P.STATE_PAUSED:
                self._out_of_band(P.Resume(), P.STATE_RECEIVING)
        elif self._own(ack.job_id, ack.run_id) and ack.state == P.STATE_DONE:
            resume = self.job.layer_count
        elif self._own(ack.job_id, ack.run_id):
            raise ControllerFaultError(f"{self.name}: the controller left the job ({P.STATE_NAMES.get(ack.state)}) "
                                       f"after layer {ack.last_completed}")
        else:
            resume = self.first_layer
        self.log.write(event, layer=resume, boot_id=f"{ack.boot_id:08x}")
        self._restart_stream(resume)

    def _resplit(self, dead_by: float, heard: float) -> None:
        """A new session on the same port, so the frames still unacknowledged are made again at the smaller size;
        a HELLO unanswered until ``dead_by`` (the dead-link bound after the controller last answered, at
        ``heard``) is a dead link."""
        self.counters.resplits += 1
        self.log.write("resplit", payload=self.sizer.budget(self._link_payload, self.window.sack, count=False),
                       last_queued=self.last_queued)
        try:
            ack = self.session.handshake(min(time.monotonic() + 2 * self.timing.reconnect_s, dead_by), first=False,
                                         since=heard)
        except LinkDeadError as err:
            if time.monotonic() >= dead_by:
                raise
            raise LinkLost(str(err)) from None
        self._accept_hello(ack)
        self.window.stuck = 0
        self._continue_after(ack, "resume")

    # -- the data stream ---------------------------------------------------------------

    def _restart_stream(self, start: int) -> None:
        """Begin a fresh data stream (seq 0) at layer ``start``; the round count is per job, not per stream."""
        self.window.restart()
        self._generator = job_messages(self.job, self.get_layer, start, self._chunk_budget, self._negotiated,
                                       self.job_name)
        self._generator_done = start >= self.job.layer_count and self.last_completed >= self.job.layer_count - 1

    def _chunk_budget(self) -> int:
        """Payload bytes per data frame now: the negotiated maximum, shrunk while bytes are being corrupted."""
        return self.sizer.budget(self._link_payload, self.window.sack)

    def _new_frame(self) -> bool:
        """Append the next message of the stream to the window; False when the stream is exhausted."""
        if self._generator_done:
            return False
        try:
            message, layer, raw = next(self._generator)
        except StopIteration:
            self._generator_done = True
            return False
        kind, payload = P.pack_message(message)
        self.window.push(kind, payload, layer, raw)
        return True

    def _try_send(self, now: float) -> float | None:
        """Transmit frames the window, credit and pacing allow; return when pacing permits the next one."""
        window, session = self.window, self.session
        while True:
            if window.can_take_new() and not self._new_frame():
                return None
            out, skipped = window.next_to_send()
            self.counters.skipped += skipped
            if out is None:
                return None
            wait = session.pacing_wait(now, self._lead_s())
            if wait is not None:
                return wait
            if out is window.head and out.sends == 0:
                self._acked_at = now  # a new flight starts
            wire = P.encode_frame(P.Frame(out.kind, session.id, out.seq, (window.tag + 1) & 0xFFFF, out.body))
            wire_end = session.send(wire, now)
            resent = window.mark_sent(out, wire_end)
            self.counters.on_sent(out, len(wire), resent)
            self.sizer.on_sent(len(wire), resent)
            if out.kind == P.Execute.TYPE:
                self._sent_execute = max(self._sent_execute, out.layer)

    def _lead_s(self) -> float:
        """How far writes may run ahead of the wire, s: ``poll_s``, but without SACK no more than LEAD_RUNS mean
        error-free runs (1 / byte error rate each) and at least one frame, since go-back-N resends everything
        written behind a lost frame (at 1e-2 and 1 Mbaud, 5 ms of lead is ten lost frames' worth)."""
        timing, rate = self.timing, self.session.rate
        if self.window.sack or not rate:
            return timing.poll_s
        frame = P.wire_size(self.sizer.budget(self._link_payload, False, count=False) + CHUNK_HEADER)
        return min(timing.poll_s, max(frame, LEAD_RUNS / self.sizer.error_rate(False)) / rate)

    def _go_back(self, reason: str) -> None:
        """Go-back-N: retransmit every unacknowledged frame not reported held; re-split oversize frames; pause
        after too many rounds."""
        window = self.window
        if window.head is not None:
            self.sizer.on_error(0.0 if window.sack else window.behind_head(), window.head.cost)
        heard, dead_by = self._heard(), self._dead_by()
        stuck = window.go_back()
        head = window.head
        if head is not None and self.counters.resplits < self.timing.max_resplits and self._remake_smaller(head, stuck):
            self._resplit(dead_by, heard)
            return
        if stuck >= self.timing.retry_limit:
            paused = self.pause()
            self.log.write("retry-limit", seq=head.seq if head else None, layer=head.layer if head else None,
                           reason=reason, paused=paused)
            raise RetryLimitError(
                f"{self.name}: no progress after {self.timing.retry_limit} retransmissions "
                f"(layer {head.layer if head else '?'}, last: {reason}); the job is "
                f"{'paused' if paused else 'stopped'} on the controller after layer {self.last_completed}; "
                "check the link, then rerun with --resume")

    def _remake_smaller(self, head: OutFrame, stuck: int) -> bool:
        """Whether to re-split: the oldest frame is twice the chosen size once sent 3 times, or larger once it failed
        2/3 of the retry cap's rounds in a row, when a chunk also caps the size at half its own (the estimate lags)."""
        late = stuck >= 2 * self.timing.retry_limit // 3
        if late and head.raw and head.payload > MIN_CHUNK_PAYLOAD:
            self.sizer.cap(head.payload // 2)
            return True
        ratio = 1.0 if late else 2.0 if head.sends >= 3 else float("inf")
        return head.payload > ratio * self.sizer.budget(self._link_payload, self.window.sack, count=False)

    def _check_claim(self, last_queued: int, last_completed: int) -> None:
        """A progress claim beyond the job, or of layers this run never sent, is a protocol error (exit 12)."""
        last = self.job.layer_count - 1
        sent = max(self._sent_execute, self._queued_base, self.first_layer - 1)
        if last_completed > last or last_queued > last or last_completed > last_queued or last_queued > sent:
            raise ProtocolError(
                f"{self.name}: the controller claims layers up to {last_completed} printed and {last_queued} queued, "
                f"but the job has layers 0..{last} and this run sent up to layer {sent}: a controller fault; "
                f"stopped after layer {self.last_completed}")

    def _note_progress(self, last_queued: int, last_completed: int) -> None:
        """Check a progress claim of this run, log each newly executed layer and report progress."""
        self._check_claim(last_queued, last_completed)
        if last_queued > self.last_queued:
            self.last_queued = last_queued
            self._last_advance = time.monotonic()
        if last_completed <= self.last_completed:
            return
        self._last_advance = time.monotonic()
        for layer in range(max(self.last_completed + 1, self.first_layer), last_completed + 1):
            c = self.counters
            self.log.write("layer", layer=layer, bytes=c.layer_bytes.pop(layer, 0),
                           retries=c.layer_retries.pop(layer, 0),
                           status={"state": P.STATE_NAMES.get(self.state, str(self.state)),
                                   "last_completed": last_completed, "credit": self.window.credit})
        self.last_completed = last_completed
        if self.on_progress is not None:
            self.on_progress(Progress(last_completed, last_completed - self.first_layer + 1,
                                      self.job.layer_count - self.first_layer, self.counters.bytes_sent,
                                      time.monotonic() - self._started))

    def _on_status(self, frame: P.Frame, status: P.Status) -> None:
        """React to STATUS: reset, error or abort stop the print; otherwise it acknowledges like an ACK."""
        if self.boot_id is not None and status.boot_id != self.boot_id:
            self._reset_detected(status.boot_id, status.job_id, status.last_completed)
        if frame.session != self.session.id:
            return
        self.state = status.state
        if self._own(status.job_id, status.run_id):
            self._note_progress(status.last_queued, status.last_completed)
        if status.state == P.STATE_ERROR:
            raise ControllerFaultError(
                f"{self.name}: the controller reports {P.ERROR_NAMES.get(status.error, f'error {status.error}')} "
                f"at layer {status.error_layer}; the job is stopped after layer {status.last_completed} "
                f"(fix the printer, then rerun with --from-layer {status.last_completed + 1})")
        if status.state == P.STATE_ABORTED and self._own(status.job_id, status.run_id):
            raise ControllerFaultError(f"{self.name}: the controller aborted the job after layer "
                                       f"{status.last_completed}")
        if self._on_ack(frame.ack, status.credit):
            self._advanced()

    def _on_ack(self, ack_seq: int, credit: int, held: int | None = None) -> bool:
        """The window's cumulative acknowledgement, the frames it acknowledged counted for the sizer."""
        frames = self.window.frames
        before, cost = len(frames), sum(out.cost for out in frames)
        progressed = self.window.on_ack(ack_seq, credit, held)
        if progressed:
            self.sizer.on_acked(before - len(frames), cost - sum(out.cost for out in frames))
        return progressed

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
        if frame.session != self.session.id:
            return
        if isinstance(message, P.Ack):
            if self._on_ack(frame.ack, message.credit, message.held):
                self._advanced()
            if self._own(message.job_id, message.run_id):
                self._note_progress(message.last_queued, message.last_completed)
        elif isinstance(message, P.Nak):
            if self._on_ack(frame.ack, message.credit, message.held):
                self._advanced()
            self.counters.naks += 1
            if self.window.nak_calls_for_go_back(frame.ack, message.tag):
                self._go_back(f"NAK ({message.reason})")

    def _finished(self) -> bool:
        """True when every frame is acknowledged and the last layer executed."""
        return self._generator_done and self.window.empty and self.last_completed >= self.job.layer_count - 1

    def _advanced(self) -> None:
        """The acknowledgement moved on."""
        self._last_advance = self._acked_at = time.monotonic()

    def _check_stall(self, now: float) -> None:
        """Stop (exit 12) a controller that neither acknowledges nor progresses, whatever it answers."""
        idle = self.last_queued <= self.last_completed
        limit = self.timing.stall_s if idle else self.timing.head_stall_s
        if now - self._last_advance > limit:
            raise ProtocolError(
                f"{self.name}: the controller acknowledged nothing and completed no layer for {limit:g} s "
                f"({'nothing queued' if idle else 'layers queued'}, credit {self.window.credit} bytes); stopped "
                f"after layer {self.last_completed}")

    def _pump(self) -> None:
        """The main loop: send, read, time out, until the last layer is executed."""
        timing, session = self.timing, self.session
        while not self._finished():
            try:
                now = time.monotonic()
                wait_until = self._try_send(now)
                for frame in session.read_frames(block=wait_until is None):
                    self._dispatch(frame)
                now = time.monotonic()
                if self.window.timed_out(now, timing.ack_timeout_s, timing.max_backoff):
                    self.counters.timeouts += 1
                    self._go_back("timeout")
                if now - session.last_rx > timing.silence_s:
                    raise LinkLost(f"no frame for {timing.silence_s:g} s")
                if self.window.in_flight and now - self._acked_at > timing.silence_s:
                    raise LinkLost(f"nothing acknowledged for {timing.silence_s:g} s (the controller reads nothing?)")
                self._check_stall(now)
                session.keepalive(now)
                if wait_until is not None and wait_until > now and not session.waiting():
                    time.sleep(min(wait_until - now, timing.poll_s))
            except LinkLost as lost:
                self._reconnect(str(lost))


def print_job(port: str, job: JobSpec, get_layer: LayerSource, *, baud: int | None = None,
              from_layer: int | None = None, resume: bool = False, restart: bool = False,
              timing: LinkTiming = LinkTiming(), log_path: Path | None = None,
              on_progress: Callable[[Progress], None] | None = None, connector: Connector | None = None,
              max_payload: int = 1024, encodings: int = P.ALL_ENCODINGS, features: int = P.ALL_FEATURES,
              label: str = "this stack", name: str = "") -> PrintResult:
    """Print ``job`` on ``port`` (device path, pyserial URL or ``sim://``); raise a PrinterError subclass on failure.

    ``label`` names the stack in messages, ``name`` goes to the controller with the job (JOB_BEGIN). ``baud``
    None: the rate a simulated controller's pseudo-terminal announces, else ports.DEFAULT_BAUD.
    """
    own = connector is None
    connector = connector or connector_for(port, baud)
    log = PrintLog(log_path)
    try:
        link = PrinterLink(connector, job, get_layer, timing=timing, max_payload=max_payload, encodings=encodings,
                           features=features, log=log, on_progress=on_progress, label=label, name=name)
        return link.run(from_layer, resume=resume, restart=restart)
    finally:
        log.close()
        if own:
            connector.close()
