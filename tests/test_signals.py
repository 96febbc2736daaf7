"""SIGTERM and SIGHUP end a heoslice command like Ctrl-C: Interrupted (a KeyboardInterrupt), exit 128 + signum."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest

from heoslice.errors import Interrupted

WAIT = ("import os, signal, sys, time\nfrom heoslice.signals import interrupt_on_terminating_signals\n"
        "interrupt_on_terminating_signals()\n"
        "try:\n    print('ready', flush=True); time.sleep(30)\n"
        "except KeyboardInterrupt as err:\n    print(type(err).__name__, err.exit_code, flush=True)\n")


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_terminating_signals_raise_interrupted(signum):
    """After the handler is installed, SIGTERM / SIGHUP arrive as Interrupted with exit_code 128 + signum."""
    proc = subprocess.Popen([sys.executable, "-c", WAIT], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "ready"
    proc.send_signal(signum)
    out, _ = proc.communicate(timeout=20)
    assert out.split() == ["Interrupted", str(128 + signum)]


def test_interrupted_is_a_keyboard_interrupt():
    """Every path that handles Ctrl-C handles Interrupted too."""
    assert issubclass(Interrupted, KeyboardInterrupt) and Interrupted(15).exit_code == 143
