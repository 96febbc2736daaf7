"""Effective throughput of `heoslice print` on the simulator, against the link rate it models.

Run: python benchmarks/bench_print.py [--baud 115200] [--kib 96] [--seed 1]

Layers are incompressible random bytes (so encoding cannot inflate the figure);
"effective throughput" is layer bytes delivered and executed per second of the
print, divided by the modelled link rate (baud / 10 bytes per second). The same job
is also printed as compressible masks to show the effect of chunk encoding.
"recovery" is what the host and simulator negotiated: SACK (the default: frames after
a gap are held by the controller) or plain go-back-N (the host does not offer SACK),
to show what each costs on the noisy link.
Targets (issue 5): >= 90 % with no faults, >= 70 % with a byte error rate of 1e-3; and (issue 47) masks at
1e-2 finish, without SACK too.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from heoslice.printing import print_job
from heoslice.printing import protocol as P
from heoslice.printing.simulator import (
    FaultSpec,
    SimConfig,
    SimConnector,
    SimController,
)

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from printing_jobs import random_job, synthetic_job  # noqa: E402  (test fixtures, beside the tests)


def run(job, get_layer, baud: int, error_rate: float, seed: int, features: int = P.ALL_FEATURES) -> dict:
    """Print ``job`` on a fresh simulator, the host offering ``features``; figures of the run."""
    sim = SimController(SimConfig(baud=baud, layer_time_s=0.0, seed=seed), FaultSpec(byte_error_rate=error_rate))
    connector = SimConnector(sim)
    start = time.monotonic()
    try:
        result = print_job("sim://", job, get_layer, connector=connector, features=features)
    finally:
        connector.close()
    elapsed = time.monotonic() - start
    executed = sim.executed_layers(job.job_id)
    assert executed == list(range(job.layer_count)), "layers not executed exactly once in order"
    crcs = [e.crc for e in sim.executed]
    assert crcs == [P.crc32(b"".join(get_layer(k))) for k in range(job.layer_count)], "layer CRC mismatch"
    return {"raw": result.raw_bytes, "wire": result.bytes_sent, "elapsed": elapsed,
            "efficiency": result.raw_bytes / elapsed / (baud / 10.0), "resent": result.frames_retransmitted,
            "frames": result.frames_sent, "recovery": "SACK" if result.sack else "go-back-N"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baud", type=int, default=115200, help="modelled link rate, bits/s")
    parser.add_argument("--kib", type=int, default=96, help="layer data per run, KiB")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    rows = max(1, args.kib * 1024 // 256 // 16)
    random_layers = random_job(16, rows, seed=args.seed)
    mask_layers = synthetic_job(16, 2048, rows, seed=args.seed)
    print(f"link: {args.baud} baud = {args.baud / 10:.0f} B/s modelled; 16 layers x {rows * 256} bytes")
    print(f"{'data':<8} {'byte errors':>11} {'recovery':>10} {'effective B/s':>14} {'of link':>8} "
          f"{'wire bytes':>11} {'frames':>7} {'resent':>7} {'seconds':>8}")
    cases = [("random", random_layers, 0.0, P.ALL_FEATURES), ("random", random_layers, 1e-3, P.ALL_FEATURES),
             ("random", random_layers, 1e-3, 0), ("masks", mask_layers, 0.0, P.ALL_FEATURES),
             ("masks", mask_layers, 1e-3, P.ALL_FEATURES), ("masks", mask_layers, 1e-2, P.ALL_FEATURES),
             ("masks", mask_layers, 1e-2, 0)]
    for label, (job, get_layer), error_rate, features in cases:
        figures = run(job, get_layer, args.baud, error_rate, args.seed, features)
        print(f"{label:<8} {error_rate:>11g} {figures['recovery']:>10} {figures['raw'] / figures['elapsed']:>14.0f} "
              f"{figures['efficiency']:>8.1%} {figures['wire']:>11} {figures['frames']:>7} "
              f"{figures['resent']:>7} {figures['elapsed']:>8.2f}")


if __name__ == "__main__":
    main()
