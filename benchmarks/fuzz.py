"""A long fuzz run of heoslice's readers of untrusted files (PLY, manifest, layer TIFFs).

    python benchmarks/fuzz.py --minutes 10          # repeat tests/test_fuzz.py with fresh seeds for 10 minutes
    python benchmarks/fuzz.py --examples 20000      # one pass, 20000 examples per fuzz test

Each pass runs tests/test_fuzz.py with HEOSLICE_FUZZ_EXAMPLES examples per test and a
new random seed; the first failure stops the run and pytest prints the shrunk input.
"""

from __future__ import annotations

import argparse
import os
import random
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, default=0.0, help="keep fuzzing with new seeds this long")
    parser.add_argument("--examples", type=int, default=2000, help="examples per fuzz test and pass")
    args = parser.parse_args()
    deadline = time.monotonic() + 60.0 * args.minutes
    environment = {**os.environ, "HEOSLICE_FUZZ_EXAMPLES": str(args.examples)}
    passes = 0
    while True:
        seed = random.SystemRandom().randrange(2**32)
        started = time.monotonic()
        done = subprocess.run([sys.executable, "-m", "pytest", str(ROOT / "tests" / "test_fuzz.py"), "-q", "-x",
                               "-p", "no:cacheprovider", f"--hypothesis-seed={seed}"], cwd=ROOT, env=environment)
        passes += 1
        print(f"pass {passes}: seed {seed}, {args.examples} examples per test, "
              f"{time.monotonic() - started:.0f} s, {'ok' if done.returncode == 0 else 'FAILED'}", flush=True)
        if done.returncode != 0:
            return done.returncode
        if time.monotonic() >= deadline:
            return 0


if __name__ == "__main__":
    sys.exit(main())
