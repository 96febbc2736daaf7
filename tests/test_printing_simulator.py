"""The simulated controller: exactly-once execution, CRC checks, go-back-N replies, credit, faults, pacing."""

from __future__ import annotations

import time

import numpy as np
import pytest

from heoslice.errors import PortError
from heoslice.printing import protocol as P
from heoslice.printing.simulator import (
    FaultSpec,
    SimConfig,
    SimController,
    pipe_pair,
    sim_from_url,
)
from heoslice.printing.simulator.faults import FaultInjector

FAST = dict(baud=10_000_000, layer_time_s=0.001, status_interval_s=0.05)


class RawHost:
    """A hand-driven host on an in-process pipe: send messages, collect the controller's replies."""

    def __init__(self, sim: SimController, session: int = 0x4242):
        self.port, transport = pipe_pair()
        self.port.timeout = 0.01
        self.sim = sim.start(transport)
        self.session = session
        self.splitter = P.FrameSplitter()
        self.seq = 0
        self.tag = 0
        self.received: list[tuple[P.Frame, P.Message]] = []

    def send(self, message, seq=None, session=None, version=P.PROTOCOL_VERSION):
        """Write one frame; data messages get the next seq unless one is given."""
        if message.TYPE in P.DATA_TYPES and seq is None:
            seq, self.seq = self.seq, (self.seq + 1) % P.SEQ_MODULUS
        self.tag += 1
        frame = P.message_frame(message, self.session if session is None else session, seq or 0, self.tag, version)
        self.port.write(P.encode_frame(frame))

    def wait(self, predicate, timeout=3.0):
        """Read until predicate(frame, message) holds; return that pair (fails the test on timeout)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            for item in self.splitter.feed(self.port.read(4096)):
                if isinstance(item, P.Frame):
                    pair = (item, P.unpack_message(item.type, item.payload))
                    self.received.append(pair)
                    if predicate(*pair):
                        return pair
        raise AssertionError("the controller did not send the expected frame")

    def hello(self, features=0):
        self.send(P.Hello(P.PROTOCOL_VERSION, 1024, P.ALL_ENCODINGS, features))
        return self.wait(lambda f, m: isinstance(m, P.HelloAck))[1]

    def layer(self, index, data: bytes, crc=None, encoding=P.ENC_RAW):
        self.send(P.LayerBegin(index, 1, len(data), P.crc32(data) if crc is None else crc))
        half = len(data) // 2
        for offset, part in ((0, data[:half]), (half, data[half:])):
            code, encoded = P.encode_chunk(part, (1 << encoding) | 1)
            self.send(P.Chunk(index, 0, offset, code, len(part), encoded))
        self.send(P.LayerEnd(index))
        self.send(P.Execute(index))

    def status(self, predicate, timeout=3.0):
        return self.wait(lambda f, m: isinstance(m, P.Status) and predicate(m), timeout)[1]

    def close(self):
        self.port.close()
        self.sim.stop()


@pytest.fixture
def host():
    hosts = []

    def make(config=SimConfig(**FAST), faults=FaultSpec()):
        hosts.append(RawHost(SimController(config, faults)))
        return hosts[-1]

    yield make
    for h in hosts:
        h.close()


def layer_bytes(index: int, size: int = 40) -> bytes:
    return np.random.default_rng(index).integers(0, 4, size, dtype=np.uint8).tobytes()


def test_layers_execute_in_order_with_the_received_crc(host):
    """Layers sent in order are executed once each, in order, and recorded with the CRC of the data received."""
    h = host()
    h.hello()
    h.send(P.JobBegin(7, 0, 5, 1, 320, 1))
    for k in range(5):
        h.layer(k, layer_bytes(k), encoding=P.ENC_PACKBITS)
    h.send(P.JobEnd(7))
    h.status(lambda s: s.state == P.STATE_DONE)
    assert [(e.layer, e.crc) for e in h.sim.executed] == [(k, P.crc32(layer_bytes(k))) for k in range(5)]


def test_repeated_execute_after_reconnect_runs_once(host):
    """A layer resent whole in a new session (after its EXECUTE was applied) is not executed again."""
    h = host()
    h.hello()
    h.send(P.JobBegin(7, 0, 3, 1, 320, 1))
    h.layer(0, layer_bytes(0))
    h.status(lambda s: s.last_completed == 0)
    h.seq = 0
    ack = h.hello()
    assert ack.last_queued == 0 and ack.job_id == 7
    h.send(P.JobBegin(7, 1, 3, 1, 320, 1))
    h.layer(0, layer_bytes(0))
    h.layer(1, layer_bytes(1))
    h.status(lambda s: s.last_completed == 1)
    assert h.sim.executed_layers() == [0, 1]


def test_layer_crc_mismatch_stops_the_job(host):
    """A layer whose data does not match LAYER_BEGIN's CRC is refused: error state, nothing executed."""
    h = host()
    h.hello()
    h.send(P.JobBegin(7, 0, 3, 1, 320, 1))
    h.layer(0, layer_bytes(0), crc=P.crc32(layer_bytes(0)) ^ 1)
    status = h.status(lambda s: s.state == P.STATE_ERROR)
    assert (status.error, status.error_layer) == (P.ERR_LAYER_CRC, 0)
    assert h.sim.executed == []


def test_execute_out_of_order_is_an_error(host):
    """EXECUTE of a layer beyond the next one is refused (error 2), never executed."""
    h = host()
    h.hello()
    h.send(P.JobBegin(7, 0, 3, 1, 320, 1))
    h.send(P.Execute(2))
    status = h.status(lambda s: s.state == P.STATE_ERROR)
    assert status.error == P.ERR_OUT_OF_ORDER and h.sim.executed == []


def test_go_back_n_replies(host):
    """A gap is NAKed with the offending frame's tag, a duplicate re-ACKed, a CRC failure NAKed with reason 3."""
    h = host()
    h.hello()
    h.send(P.JobBegin(7, 0, 3, 1, 320, 1), seq=0)
    h.wait(lambda f, m: isinstance(m, P.Ack) and f.ack == 1)
    h.send(P.LayerEnd(0), seq=5)
    frame, nak = h.wait(lambda f, m: isinstance(m, P.Nak))
    assert (frame.ack, nak.tag, nak.reason) == (1, h.tag, P.NAK_OUT_OF_ORDER)
    h.send(P.JobBegin(7, 0, 3, 1, 320, 1), seq=0)
    h.wait(lambda f, m: isinstance(m, P.Ack) and f.ack == 1)
    assert h.sim.stats["duplicates"] == 1
    wire = bytearray(P.encode_frame(P.message_frame(P.LayerEnd(0), h.session, 1, 99)))
    wire[4] ^= 0x40
    h.port.write(bytes(wire))
    frame, nak = h.wait(lambda f, m: isinstance(m, P.Nak) and m.reason == P.NAK_BAD_FRAME)
    assert frame.ack == 1


def gap_then_fill(h: RawHost, data: bytes) -> list[tuple[P.Frame, P.Message]]:
    """Send job and layer 0 as DATA frames with seq 2 (the first DATA) missing, then seq 2; return the replies
    to the frames after the gap, in order."""
    h.send(P.JobBegin(7, 0, 1, 1, 8 * len(data), 1))
    h.send(P.LayerBegin(0, 1, len(data), P.crc32(data)))
    h.wait(lambda f, m: isinstance(m, P.Ack) and f.ack == 2)
    time.sleep(0.05)  # let the controller apply them, so the credit below counts held frames only
    third = len(data) // 3
    h.seq = 3
    start = len(h.received)
    h.send(P.Data(data[third:2 * third]))
    h.send(P.Data(data[2 * third:]))
    h.send(P.LayerEnd(0))
    h.send(P.Execute(0))
    h.wait(lambda f, m: sum(isinstance(r, P.Nak) for _, r in h.received[start:]) >= 4)
    h.send(P.Data(data[:third]), seq=2)
    h.wait(lambda f, m: isinstance(m, P.Ack) and f.ack in (3, 7))
    return h.received[start:]


@pytest.mark.parametrize("host_offers, controller_offers", [(1, 1), (1, 0), (0, 1)])
def test_sack_holds_frames_after_a_gap_only_when_negotiated(host, host_offers, controller_offers):
    """With SACK enabled by both sides, frames after a gap are held (NAKed, reported in ``held``, using credit) and
    applied once the gap is filled; otherwise (plain go-back-N) they are discarded and must be resent. Either way
    the layer executes exactly once with the host's CRC."""
    h = host(SimConfig(**{**FAST, "features": controller_offers}))
    sack = bool(host_offers and controller_offers)
    assert h.hello(features=host_offers).features == (P.FEATURE_SACK if sack else 0)
    data = layer_bytes(0, 90)
    replies = gap_then_fill(h, data)
    naks = [(f, m) for f, m in replies if isinstance(m, P.Nak)][:4]
    assert [(f.ack, m.reason) for f, m in naks] == [(2, P.NAK_OUT_OF_ORDER)] * 4
    assert [m.tag for f, m in naks] == list(range(h.tag - 4, h.tag))
    costs = [30 + P.FRAME_OVERHEAD, 30 + P.FRAME_OVERHEAD, 4 + P.FRAME_OVERHEAD, 4 + P.FRAME_OVERHEAD]
    frame, ack = replies[-1]
    assert ack.held == 0
    if sack:
        assert [m.held for f, m in naks] == [0b1, 0b11, 0b111, 0b1111]
        assert [m.credit for f, m in naks] == [h.sim.config.rx_buffer - sum(costs[:i + 1]) for i in range(4)]
        assert frame.ack == 7
    else:
        assert all(m.held == 0 for f, m in naks) and frame.ack == 3
        h.seq = 3
        h.send(P.Data(data[30:60]))
        h.send(P.Data(data[60:]))
        h.send(P.LayerEnd(0))
        h.send(P.Execute(0))
    h.send(P.Data(data[30:60]), seq=3)  # a late copy of a frame already applied: a duplicate
    h.send(P.JobEnd(7), seq=7)
    h.status(lambda s: s.state == P.STATE_DONE)
    assert [(e.layer, e.crc) for e in h.sim.executed] == [(0, P.crc32(data))]
    assert h.sim.stats["duplicates"] >= 1


def test_sack_across_the_sequence_wrap(host):
    """Held bits and the in-order release of held frames follow 16-bit sequence arithmetic across 65535 -> 0."""
    h = host()
    h.hello(features=P.FEATURE_SACK)
    h.sim.expected = 65534
    data = layer_bytes(4, 60)
    h.send(P.JobBegin(7, 0, 1, 1, 8 * len(data), 1), seq=65534)
    h.wait(lambda f, m: isinstance(m, P.Ack) and f.ack == 65535)
    h.send(P.Data(data[:30]), seq=0)
    h.send(P.Data(data[30:]), seq=1)
    h.send(P.LayerEnd(0), seq=2)
    frame, nak = h.wait(lambda f, m: isinstance(m, P.Nak) and m.held == 0b111)
    assert frame.ack == 65535
    h.send(P.LayerBegin(0, 1, len(data), P.crc32(data)), seq=65535)
    frame, ack = h.wait(lambda f, m: isinstance(m, P.Ack) and f.ack != 65535)
    assert (frame.ack, ack.held) == (3, 0)
    h.send(P.Execute(0), seq=3)
    h.status(lambda s: s.last_completed == 0)
    assert [(e.layer, e.crc) for e in h.sim.executed] == [(0, P.crc32(data))]


def test_held_frames_never_block_the_gap(host):
    """When held frames leave too little credit for the missing frame, the controller drops the held frames
    farthest ahead (clearing their ``held`` bits) and takes the missing one: no deadlock; the layer still
    executes once with the host's CRC."""
    h = host(SimConfig(**{**FAST, "rx_buffer": 300}))
    h.hello(features=P.FEATURE_SACK)
    data = layer_bytes(3, 250)
    h.send(P.JobBegin(7, 0, 1, 1, 8 * len(data), 1))
    h.send(P.LayerBegin(0, 1, len(data), P.crc32(data)))
    h.wait(lambda f, m: isinstance(m, P.Ack) and f.ack == 2)
    time.sleep(0.05)
    parts = [data[:70], data[70:130], data[130:190], data[190:]]
    for seq in (3, 4, 5):
        h.send(P.Data(parts[seq - 2]), seq=seq)
    frame, nak = h.wait(lambda f, m: isinstance(m, P.Nak) and m.held == 0b111)
    assert nak.credit == 300 - 3 * (60 + P.FRAME_OVERHEAD) < 70 + P.FRAME_OVERHEAD
    h.send(P.Data(parts[0]), seq=2)
    frame, ack = h.wait(lambda f, m: isinstance(m, P.Ack) and f.ack > 2)
    assert (frame.ack, ack.held) == (5, 0) and h.sim.stats["held_dropped"] == 1
    h.send(P.Data(parts[3]), seq=5)
    h.send(P.LayerEnd(0), seq=6)
    h.send(P.Execute(0), seq=7)
    h.status(lambda s: s.last_completed == 0)
    assert [(e.layer, e.crc) for e in h.sim.executed] == [(0, P.crc32(data))]


def test_data_writes_at_the_cursor(host):
    """DATA writes at the cursor that LAYER_BEGIN sets to 0 and each CHUNK or DATA advances, across channels;
    a DATA reaching past the layer's end is refused (error 1), nothing executed."""
    h = host()
    h.hello()
    first, second = layer_bytes(1, 20), layer_bytes(2, 20)
    h.send(P.JobBegin(7, 0, 2, 2, 160, 1))
    h.send(P.LayerBegin(0, 2, 20, P.crc32(first + second)))
    code, packed = P.encode_chunk(first[:12], 1 << P.ENC_PACKBITS)
    h.send(P.Chunk(0, 0, 0, code, 12, packed))
    h.send(P.Data(first[12:] + second[:5]))
    h.send(P.Data(second[5:]))
    h.send(P.LayerEnd(0))
    h.send(P.Execute(0))
    h.status(lambda s: s.last_completed == 0)
    assert [(e.layer, e.crc) for e in h.sim.executed] == [(0, P.crc32(first + second))]
    h.send(P.LayerBegin(1, 2, 20, 0))
    h.send(P.Data(bytes(39)))
    h.send(P.Data(bytes(2)))
    status = h.status(lambda s: s.state == P.STATE_ERROR)
    assert (status.error, status.error_layer) == (P.ERR_LAYER_CRC, 1)
    assert h.sim.executed_layers() == [0]


def test_receive_buffer_is_bounded_and_credit_honest(host):
    """With the head paused, the buffer fills: credits fall, and a frame beyond the credit is NAKed (reason 2)."""
    h = host(SimConfig(**{**FAST, "rx_buffer": 600, "print_queue": 1}))
    ack = h.hello()
    assert ack.rx_buffer == 600
    h.send(P.Pause())
    h.status(lambda s: s.state in (P.STATE_PAUSED, P.STATE_IDLE))
    h.send(P.JobBegin(7, 0, 40, 1, 320, 1))
    for k in range(6):
        h.layer(k, layer_bytes(k, 60))
    h.wait(lambda f, m: isinstance(m, P.Nak) and m.reason == P.NAK_NO_CREDIT)
    credits = [m.credit for f, m in h.received if isinstance(m, (P.Ack, P.Nak, P.Status))]
    assert min(credits) >= 0 and max(credits) <= 600 and min(credits) < 100
    assert h.sim.executed == []
    h.send(P.Resume())
    h.status(lambda s: s.last_completed >= 0)


def test_pause_resume_abort_bypass_the_queue(host):
    """PAUSE holds the head with layers queued, RESUME releases them, ABORT empties the queue at once."""
    h = host(SimConfig(**{**FAST, "layer_time_s": 0.05}))
    h.hello()
    h.send(P.Pause())
    h.send(P.JobBegin(7, 0, 10, 1, 320, 1))
    for k in range(3):
        h.layer(k, layer_bytes(k))
    h.status(lambda s: s.last_queued == 1 and s.state == P.STATE_PAUSED)
    assert h.sim.executed == []
    h.send(P.Resume())
    h.status(lambda s: s.last_completed >= 0)
    h.send(P.Abort())
    status = h.status(lambda s: s.state == P.STATE_ABORTED)
    time.sleep(0.15)
    assert len(h.sim.executed) <= status.last_completed + 2 and len(h.sim.executed) < 3


def test_version_mismatch_is_answered_in_the_controllers_version(host):
    """A controller of another version answers HELLO with its own version and accepts no session."""
    h = host(SimConfig(**{**FAST, "version": 1}))
    h.send(P.Hello(2, 1024, 7, P.FEATURE_SACK))
    frame, ack = h.wait(lambda f, m: isinstance(m, P.HelloAck))
    assert frame.version == 1 and ack.version == 1 and ack.features == 0
    assert h.sim.session == 0


def test_reset_keeps_persisted_progress_and_changes_boot_id(host):
    """A reset mid-layer draws a new boot id, forgets the session, keeps job id and last completed layer
    (the last layer the head executed before the reset, or first_layer - 1 = -1 when the head had executed
    none yet: layers 0 and 1 may still be queued when layer 2's first chunk resets it, on a loaded machine)."""
    h = host(faults=FaultSpec(reset_at_layer=2))
    first = h.hello()
    h.send(P.JobBegin(7, 0, 5, 1, 320, 1))
    # the job begun before any layer is sent: a reset loses input not yet applied, JOB_BEGIN too on a loaded machine
    h.status(lambda s: s.job_id == 7)
    for k in range(3):
        h.layer(k, layer_bytes(k))
    status = h.status(lambda s: s.boot_id != first.boot_id)
    assert status.job_id == 7 and status.state == P.STATE_IDLE
    executed = h.sim.executed_layers()
    assert status.last_completed == (executed[-1] if executed else -1) and status.last_completed <= 1
    assert h.sim.session == 0


def test_persistent_hardware_fault(host):
    """A hardware fault at layer 2 stops the head there and survives a new HELLO."""
    h = host(faults=FaultSpec(fail_at_layer=2))
    h.hello()
    h.send(P.JobBegin(7, 0, 5, 1, 320, 1))
    for k in range(4):
        h.layer(k, layer_bytes(k))
    status = h.status(lambda s: s.state == P.STATE_ERROR)
    assert (status.error, status.error_layer) == (P.ERR_HARDWARE, 2)
    h.seq = 0
    assert h.hello().state == P.STATE_ERROR
    assert h.sim.executed_layers() == [0, 1]


def test_faults_are_seeded():
    """The same seed corrupts the same bytes; another seed other bytes; rates match the spec within 4 sigma."""
    data = bytes(100_000)
    one = FaultInjector(FaultSpec(), 3).corrupt(data, 0.01, 0.0)
    two = FaultInjector(FaultSpec(), 3).corrupt(data, 0.01, 0.0)
    other = FaultInjector(FaultSpec(), 4).corrupt(data, 0.01, 0.0)
    assert one == two and one != other
    hits = np.count_nonzero(np.frombuffer(one, np.uint8))
    assert abs(hits - 1000) < 4 * np.sqrt(1000)
    dropped = FaultInjector(FaultSpec(), 3).corrupt(data, 0.0, 0.01)
    assert abs((len(data) - len(dropped)) - 1000) < 4 * np.sqrt(1000)


def test_link_pacing_model():
    """Bytes arrive at the modelled line rate: n bytes take n * 10 / baud * time_scale seconds after the wire frees."""
    sim = SimController(SimConfig(baud=9600, time_scale=0.5))
    sim._on_bytes(b"\x01" * 99 + b"\x00" + b"\x02" * 50, now=100.0)
    (t1, p1), (t2, p2) = sim._arrivals
    assert (len(p1), len(p2)) == (100, 50)
    assert t1 == pytest.approx(100.0 + 100 * 10 / 9600 * 0.5)
    assert t2 == pytest.approx(t1 + 50 * 10 / 9600 * 0.5)
    sim._on_bytes(b"\x03\x00", now=100.01)
    assert sim._arrivals[-1][0] == pytest.approx(t2 + 2 * 10 / 9600 * 0.5)


def test_sim_url_options():
    """sim:// query keys set SimConfig and FaultSpec fields; unknown keys and non-numbers are refused."""
    config, faults = sim_from_url("sim://?baud=9600&layer_time_s=0.5&byte_error_rate=1e-3&reset_at_layer=4")
    assert (config.baud, config.layer_time_s, faults.byte_error_rate, faults.reset_at_layer) == (9600, 0.5, 1e-3, 4)
    with pytest.raises(PortError, match="unknown sim:// option 'colour'"):
        sim_from_url("sim://?colour=3")
    with pytest.raises(PortError, match="not a number"):
        sim_from_url("sim://?baud=fast")
