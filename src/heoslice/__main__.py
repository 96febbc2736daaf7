"""``python -m heoslice``: the ending signals are handled before anything heavy is imported."""

import sys

from heoslice.signals import interrupt_on_terminating_signals

interrupt_on_terminating_signals()
try:
    from heoslice.cli import main
except KeyboardInterrupt as interrupt:
    print("heoslice: interrupted", file=sys.stderr)
    sys.exit(getattr(interrupt, "exit_code", 130))

if __name__ == "__main__":  # not when a spawned worker process imports this module as its parent's main
    main()
