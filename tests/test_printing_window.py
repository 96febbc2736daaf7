"""The send window as a pure state machine, driven by events without a clock, a port or a controller."""

from __future__ import annotations

import ast
from pathlib import Path

from heoslice.printing import protocol as P
from heoslice.printing.window import FrameSizer, SendWindow

PRINTING = Path(__file__).resolve().parents[1] / "src" / "heoslice" / "printing"


def window_with(frames: int, credit: int = 10_000, window: int = 8, sack: bool = True) -> SendWindow:
    w = SendWindow()
    w.configure(window, credit, sack)
    for number in range(frames):
        w.push(P.Data.TYPE, bytes(10), layer=number, raw=10)
    return w


def send_all(w: SendWindow, now: float = 0.0) -> list[int]:
    sent = []
    while True:
        out, _ = w.next_to_send()
        if out is None:
            return sent
        w.mark_sent(out, now)
        sent.append(out.seq)


def test_window_and_credit_bound_what_is_sent():
    """At most ``window`` frames and ``credit`` bytes (length + 14 each) are in flight."""
    assert send_all(window_with(10, window=4)) == [0, 1, 2, 3]
    assert send_all(window_with(10, credit=3 * 24)) == [0, 1, 2]


def test_cumulative_ack_frees_the_window_and_resets_the_round_count():
    """An ACK past seq 2 drops frames 0..2, lets three more go and clears the consecutive-rounds count."""
    w = window_with(10, window=4)
    send_all(w)
    w.go_back()
    send_all(w)
    assert w.stuck == 1
    assert w.on_ack(3, 10_000) and w.stuck == 0
    assert send_all(w) == [4, 5, 6]


def test_go_back_passes_over_held_frames():
    """With SACK, a NAK at seq 1 holding 2 and 4 resends 1, 3, 5 only, in order."""
    w = window_with(6)
    send_all(w)
    w.on_ack(1, 10_000, held=0b101)
    assert w.nak_calls_for_go_back(1, tag=w.head.tag)
    w.go_back()
    assert send_all(w) == [1, 3, 5]


def test_stale_nak_and_timeout_backoff():
    """A NAK older than the resent frame's tag is ignored; timeouts double the wait up to the cap."""
    w = window_with(3)
    send_all(w)
    old_tag = w.head.tag
    w.go_back()
    send_all(w)
    assert not w.nak_calls_for_go_back(0, old_tag) and w.nak_calls_for_go_back(0, w.head.tag)
    assert not w.timed_out(0.2, 0.25, 8) and w.timed_out(0.3, 0.25, 8) and w.backoff == 2
    assert not w.timed_out(0.45, 0.25, 8) and w.timed_out(0.55, 0.25, 8) and w.backoff == 4


def test_frame_sizer_shrinks_with_errors():
    """Clean traffic grows frames to the full payload; retransmissions shrink them."""
    sizer = FrameSizer()
    for _ in range(400):
        sizer.on_sent(1040)
    clean = sizer.budget(1024, sack=True)
    for _ in range(40):
        sizer.on_sent(1040, resent=True)
    sizer.on_error()
    assert clean > 900 and sizer.budget(1024, sack=True) < clean / 2


def test_go_back_n_estimate_reaches_the_link_rate_once_the_prior_fades():
    """Rounds of 2 in 5 frames of 60 bytes, each with 10 frames resent in vain behind it (so the old evidence is
    halved again and again), give e = -ln(3/5)/60 within 2 %: the prior is halved with the evidence (at a fixed
    weight it held the estimate at 0.85 of the link's rate, and a 1e-2 link's at about 0.55)."""
    import math

    sizer = FrameSizer()
    for index in range(4000):
        if index % 5 in (1, 3):
            for _ in range(11):
                sizer.on_sent(60)
            sizer.on_error(wasted_bytes=600, lost_bytes=60)
        else:
            sizer.on_sent(60)
            sizer.on_acked(1, 60)
    truth = -math.log(3 / 5) / 60
    assert abs(sizer.error_rate(sack=False) - truth) < 0.02 * truth


def test_a_cap_bounds_the_chunk_size_until_enough_frames_are_acknowledged():
    """cap(n) makes chunks of at most n bytes (never under MIN_CHUNK_PAYLOAD), on a clean link too, until
    CEILING_FRAMES frames are acknowledged; then the estimate's size returns."""
    from heoslice.printing.window import CEILING_FRAMES, MIN_CHUNK_PAYLOAD

    sizer = FrameSizer()
    sizer.on_acked(400, 400 * 1040)
    clean = sizer.budget(1024, sack=False)
    sizer.cap(100)
    assert clean > 500 and sizer.budget(1024, sack=False) == 100
    sizer.on_acked(CEILING_FRAMES - 1, 100 * (CEILING_FRAMES - 1))
    assert sizer.budget(1024, sack=False) == 100
    sizer.on_acked(1, 100)
    assert sizer.budget(1024, sack=False) > 500
    sizer.cap(3)
    assert sizer.budget(1024, sack=False) == MIN_CHUNK_PAYLOAD


def test_no_host_module_imports_the_simulator():
    """The host reaches the simulator only through pyserial's URL handler: no module outside simulator/ imports it."""
    offenders = []
    for path in PRINTING.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            offenders += [(path.name, n) for n in names if "simulator" in n]
    assert offenders == []


def test_go_back_n_sizing_counts_lost_frames_not_resends_and_weighs_the_waste():
    """Without SACK the error rate comes from go-back rounds per frame tried: rounds of 1 in 3 frames of 60 bytes
    give e = -ln(2/3)/60 (within the prior's pull) however many frames each round resent in vain, which inflate
    a resend-based estimate (to its cap of one frame in two lost); the bytes sent in vain behind each loss make larger frames worth it,
    and no size chosen loses more than MAX_FRAME_LOSS of its frames."""
    import math

    from heoslice.printing.window import MAX_FRAME_LOSS, optimal_frame_bytes

    sizer = FrameSizer()
    for _ in range(300):
        sizer.on_acked(2, 120)
        for _ in range(12):
            sizer.on_sent(60, resent=True)  # a round resends the lost frame and 11 behind it
        sizer.on_error(wasted_bytes=660, lost_bytes=60)
    truth = -math.log(2 / 3) / 60
    assert abs(sizer.error_rate(sack=False) - truth) < 0.1 * truth
    assert sizer.error_rate(sack=True) > 1.5 * truth and sizer.waste_bytes() == 660
    for rate in (3e-3, 1e-2, 3e-2):
        plain = optimal_frame_bytes(rate, 18, 1040, waste=1.0)
        wasteful = optimal_frame_bytes(rate, 18, 1040, waste=1.0, waste_bytes=600)
        capped = optimal_frame_bytes(rate, 18, 1040, waste=1.0, waste_bytes=600, max_loss=MAX_FRAME_LOSS)
        assert wasteful >= plain and capped <= wasteful
        assert 1 - (1 - rate) ** capped <= MAX_FRAME_LOSS or capped == 18 + 16
