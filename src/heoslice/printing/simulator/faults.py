"""The simulated controller's fault injection: which faults of a :class:`~.config.FaultSpec` strike, and when.

Byte faults (corrupted, dropped bytes), frame faults (dropped, delayed, duplicated frames), lost acks and
the one-way link fault are drawn from one generator seeded by the controller's seed, in the order the
controller meets bytes and frames, so a seed replays the same faults. Layer faults (reset, disconnect,
dead link, stop reading) strike once each, as a chunk of their layer is taken, one a chunk (several set at
one layer strike at its chunks in turn); the hardware fault and the lying progress claim are persistent.
The controller asks and acts (:mod:`.controller`); nothing here touches its state.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from heoslice.printing import protocol as P
from heoslice.printing.simulator.config import FaultSpec

#: The faults that strike once while a layer is being received, in the order they are tried.
LAYER_FAULTS = ("reset", "disconnect", "dead", "stop-reading")


@dataclass(frozen=True)
class FrameFate:
    """What the frame faults do to one received frame: stall processing (the delay fault), and how many
    times it is handled (2: duplicated)."""

    delayed: bool
    repeats: int


class FaultInjector:
    """Draws the faults of ``spec`` from a generator seeded by ``seed``; remembers the once-only layer faults
    that struck (across the controller's resets)."""

    def __init__(self, spec: FaultSpec, seed: int):
        self.spec = spec
        self._rng = np.random.default_rng(seed)
        self._fired: set[str] = set()

    def corrupt(self, data: bytes, error_rate: float, drop_rate: float) -> bytes:
        """``data`` with bytes replaced (probability ``error_rate``) and removed (``drop_rate``)."""
        buf = np.frombuffer(data, dtype=np.uint8).copy()
        if error_rate > 0:
            hit = self._rng.random(buf.size) < error_rate
            buf[hit] ^= self._rng.integers(1, 256, int(hit.sum()), dtype=np.uint8)
        if drop_rate > 0:
            buf = buf[self._rng.random(buf.size) >= drop_rate]
        return buf.tobytes()

    def inbound(self, data: bytes) -> bytes:
        """Bytes from the host as the link delivers them: corrupted and dropped by the byte faults."""
        if not self.spec.any_byte_faults:
            return data
        return self.corrupt(data, self.spec.byte_error_rate, self.spec.byte_drop_rate)

    def outbound(self, wire: bytes) -> bytes:
        """Bytes to the host as the link delivers them: corrupted (never dropped) by the byte error fault."""
        if self.spec.byte_error_rate <= 0:
            return wire
        return self.corrupt(wire, self.spec.byte_error_rate, 0.0)

    def frame_fate(self) -> FrameFate | None:
        """The frame faults of one received frame: None when it is dropped, else its :class:`FrameFate`."""
        rng, spec = self._rng, self.spec
        if spec.frame_drop_rate and rng.random() < spec.frame_drop_rate:
            return None
        delayed = bool(spec.delay_rate and rng.random() < spec.delay_rate)
        repeats = 2 if spec.frame_dup_rate and rng.random() < spec.frame_dup_rate else 1
        return FrameFate(delayed, repeats)

    def ack_lost(self) -> bool:
        """Whether the ACK of an accepted frame is lost (the frame is applied all the same)."""
        return bool(self.spec.ack_loss_rate and self._rng.random() < self.spec.ack_loss_rate)

    def data_lost(self, message: P.Message, rx_layer: int) -> bool:
        """Whether the one-way link fault eats a received data message (``rx_layer``: the layer of the latest
        layer-bearing data message received): every data frame of its layer and later ones."""
        start = self.spec.lose_data_from_layer
        has_layer = getattr(message, "layer", None) is not None
        return start is not None and rx_layer >= start and (has_layer or isinstance(message, P.Data))

    def layer_fault(self, layer: int) -> str | None:
        """The once-only layer fault (one of :data:`LAYER_FAULTS`) that strikes as a chunk of ``layer`` is
        taken, or None: the first of them set at this layer that has not struck yet."""
        spec = self.spec
        at = {"reset": spec.reset_at_layer, "disconnect": spec.disconnect_at_layer, "dead": spec.dead_at_layer,
              "stop-reading": spec.stop_reading_at_layer}
        for name in LAYER_FAULTS:
            if at[name] is not None and layer == at[name] and name not in self._fired:
                self._fired.add(name)
                return name
        return None

    def hardware_fault(self, layer: int) -> bool:
        """Whether the head fails (persistently) on reaching ``layer``."""
        return self.spec.fail_at_layer is not None and layer >= self.spec.fail_at_layer

    def claimed_completed(self, last_completed: int) -> int:
        """The last_completed reported in ACK and STATUS: the truth, unless the claim fault makes it lie."""
        claim = self.spec.claim_completed
        return last_completed if claim is None else claim
