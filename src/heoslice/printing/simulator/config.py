"""What the simulated controller is and which faults it injects: its configuration, parsed from a ``sim://`` URL.

Every option is checked here (one-line :class:`~heoslice.errors.PortError`), so a bad ``sim://?baud=0``
or ``--set`` never reaches the controller as a traceback.
"""

from __future__ import annotations

import urllib.parse
from dataclasses import dataclass, fields

from heoslice.errors import PortError
from heoslice.printing import protocol as P


@dataclass(frozen=True)
class SimConfig:
    """What the simulated controller is: its link, buffers, head speed and advertised capabilities."""

    baud: int = 115200  # modelled link rate, bits/s (10 bits per byte)
    layer_time_s: float = 0.2  # head time per layer, s
    time_scale: float = 1.0  # multiplies modelled durations (byte time, layer time)
    rx_buffer: int = 8192  # receive buffer, bytes (the credit when empty)
    window: int = 64  # frames in flight allowed
    max_payload: int = 1024  # largest frame payload accepted, bytes
    encodings: int = P.ALL_ENCODINGS
    channels: int = 4
    max_width: int = 20000  # pixels
    max_height: int = 20000  # pixels
    dpi_x: float = 0.0  # the printer's resolution, reported to the host, which refuses a stack at another;
    dpi_y: float = 0.0  # 0: not reported (a simulated printer of any resolution), nothing checked
    print_queue: int = 2  # layers held ready beside the one printing
    status_interval_s: float = 0.5  # heartbeat period, real seconds (not scaled)
    version: int = P.PROTOCOL_VERSION
    features: int = P.ALL_FEATURES  # extensions offered (bit mask, P.FEATURE_*); 0: plain go-back-N
    seed: int = 0

    @property
    def byte_time_s(self) -> float:
        """Modelled time on the wire per byte, s."""
        return 10.0 / self.baud * self.time_scale


@dataclass(frozen=True)
class FaultSpec:
    """Seeded fault injection; rates are probabilities per byte or per received frame."""

    byte_error_rate: float = 0.0  # per byte, both directions: the byte is replaced
    byte_drop_rate: float = 0.0  # per byte, host -> controller
    frame_drop_rate: float = 0.0  # per received frame
    frame_dup_rate: float = 0.0  # per received frame: handled twice
    ack_loss_rate: float = 0.0  # per accepted frame: applied, but its ACK is not sent
    delay_rate: float = 0.0  # per received frame: processing stalls for delay_s
    delay_s: float = 0.02
    reset_at_layer: int | None = None  # reboot (new boot id) at the first chunk (CHUNK or DATA) of this layer, once
    disconnect_at_layer: int | None = None  # drop the connection at the first chunk of this layer, once
    disconnect_s: float = 0.2  # how long the link stays down, s
    dead_at_layer: int | None = None  # stop answering for good at the first chunk of this layer
    fail_at_layer: int | None = None  # persistent hardware fault when the head reaches this layer
    lose_data_from_layer: int | None = None  # every data frame of this and later layers is lost (one-way link fault)
    stop_reading_at_layer: int | None = None  # stop reading the port at the first chunk of this layer (STATUS goes on)
    claim_completed: int | None = None  # every ACK and STATUS claims this last_completed (a lying controller)

    @property
    def any_byte_faults(self) -> bool:
        """True when bytes are corrupted or dropped on the wire."""
        return self.byte_error_rate > 0 or self.byte_drop_rate > 0


@dataclass(frozen=True)
class ExecutedLayer:
    """One layer the head printed: the job, the run (host id) that sent it, its index and CRC, the boot."""

    job_id: int
    layer: int
    crc: int
    boot_id: int
    run_id: int = 0


#: ``sim://`` and ``controller --pty`` model a fast link by default, so a dry run takes seconds.
FAST_PACING = {"baud": 1_000_000, "layer_time_s": 0.002}
#: ``pace=real`` / ``--real-pacing``: a 115200-baud UART and a 0.2 s head.
REAL_PACING = {"baud": 115200, "layer_time_s": 0.2}
#: Options that must be > 0; others must be >= 0; rates must also be <= 1.
_POSITIVE = frozenset({"baud", "time_scale", "status_interval_s", "print_queue"})
_BYTE_FIELDS = frozenset({"encodings", "channels", "version", "features"})


def _check(url: str, key: str, value: float) -> None:
    """PortError (one line) when option ``key`` has a value the simulator cannot model."""
    if value != value or value in (float("inf"), float("-inf")):
        raise PortError(f"{url}: option {key} must be a finite number")
    if key in _POSITIVE and value <= 0:
        raise PortError(f"{url}: option {key} must be > 0 (got {value:g})")
    if value < 0:
        raise PortError(f"{url}: option {key} must be >= 0 (got {value:g})")
    if key.endswith("_rate") and value > 1:
        raise PortError(f"{url}: option {key} is a probability, must be in [0, 1] (got {value:g})")
    if key in _BYTE_FIELDS and value > 255:
        raise PortError(f"{url}: option {key} must be at most 255 (got {value:g})")
    if key == "max_payload" and value > P.MAX_PAYLOAD_LIMIT:
        raise PortError(f"{url}: option max_payload must be at most {P.MAX_PAYLOAD_LIMIT} (got {value:g})")
    if key in ("max_width", "max_height", "rx_buffer", "window", "seed") and value >= 1 << 32:
        raise PortError(f"{url}: option {key} must be below 2^32 (got {value:g})")


def sim_from_url(url: str) -> tuple[SimConfig, FaultSpec]:
    """Parse ``sim://?baud=...&layer_time_s=...&byte_error_rate=...``: query keys are field names
    of :class:`SimConfig` and :class:`FaultSpec`, plus ``pace=fast|real`` (default fast); every value is
    checked (PortError, one line)."""
    parts = urllib.parse.urlsplit(url)
    if parts.scheme != "sim":
        raise PortError(f"{url}: not a sim:// URL")
    sim_fields = {f.name: f for f in fields(SimConfig)}
    fault_fields = {f.name: f for f in fields(FaultSpec)}
    pacing = FAST_PACING
    sim_args: dict = {}
    fault_args: dict = {}
    for key, value in urllib.parse.parse_qsl(parts.query, keep_blank_values=True):
        if key == "pace":
            if value not in ("fast", "real"):
                raise PortError(f"{url}: option pace={value!r}: expected fast or real")
            pacing = REAL_PACING if value == "real" else FAST_PACING
            continue
        target = sim_args if key in sim_fields else fault_args if key in fault_fields else None
        if target is None:
            known = ", ".join(sorted(sim_fields) + sorted(fault_fields) + ["pace"])
            raise PortError(f"{url}: unknown sim:// option {key!r} (known: {known})")
        kind = (sim_fields.get(key) or fault_fields[key]).type
        try:
            number = float(value)
        except ValueError as err:
            raise PortError(f"{url}: option {key}={value!r} is not a number") from err
        _check(url, key, number)
        if "float" not in str(kind) and number != int(number):
            raise PortError(f"{url}: option {key}={value!r} must be a whole number")
        target[key] = number if "float" in str(kind) else int(number)
    return SimConfig(**{**pacing, **sim_args}), FaultSpec(**fault_args)
