"""Tests of printing/simulator/faults.py: seeded faults replay, once-only layer faults strike once each."""

from __future__ import annotations

from heoslice.printing import protocol as P
from heoslice.printing.simulator.config import FaultSpec
from heoslice.printing.simulator.faults import FaultInjector


def test_a_seed_replays_the_same_frame_faults():
    """Two injectors of one seed drop, delay and duplicate the same frames; another seed differs."""
    spec = FaultSpec(frame_drop_rate=0.2, delay_rate=0.2, frame_dup_rate=0.2, ack_loss_rate=0.2)

    def fates(seed):
        inject = FaultInjector(spec, seed)
        return [(inject.frame_fate(), inject.ack_lost()) for _ in range(200)]

    assert fates(5) == fates(5) != fates(6)
    kinds = {(fate is None, fate and fate.delayed, fate and fate.repeats) for fate, _ in fates(5)}
    assert len(kinds) >= 3


def test_layer_faults_strike_once_in_order():
    """Faults set at one layer strike one per chunk in the order reset, disconnect, dead, stop reading, each
    once; other layers strike nothing; without faults nothing is lost, failed or claimed."""
    inject = FaultInjector(FaultSpec(reset_at_layer=3, disconnect_at_layer=3, dead_at_layer=4), 0)
    assert [inject.layer_fault(layer) for layer in (2, 3, 3, 3, 4, 4)] == [
        None, "reset", "disconnect", None, "dead", None]
    plain = FaultInjector(FaultSpec(), 0)
    assert not plain.data_lost(P.Data(b"x"), 10) and not plain.hardware_fault(10)
    assert plain.claimed_completed(7) == 7 and plain.inbound(b"abc") == b"abc"
    lossy = FaultInjector(FaultSpec(lose_data_from_layer=2, fail_at_layer=5, claim_completed=99), 0)
    assert lossy.data_lost(P.Data(b"x"), 2) and not lossy.data_lost(P.Data(b"x"), 1)
    assert lossy.hardware_fault(6) and not lossy.hardware_fault(4) and lossy.claimed_completed(7) == 99
