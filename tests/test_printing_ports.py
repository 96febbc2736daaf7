"""Opening the printer's port: a port that will not open says why and what to do in one line (the errno once, the
ports this machine has), and a print to `heoslice controller --pty` paces itself to the rate the simulator
announces on its terminal, without --baud."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tty

import pytest
from printing_jobs import disc_masks, make_stack, synthetic_job

from heoslice.errors import PortError
from heoslice.printing import print_job
from heoslice.printing.ports import DEFAULT_BAUD, SerialConnector, announce_baud, announced_baud, open_failure


def _refusal(port: str) -> str:
    """The PortError line for printing to ``port`` (exit 10)."""
    job, get_layer = synthetic_job(2, 32, 8)
    with pytest.raises(PortError) as info:
        print_job(port, job, get_layer)
    assert info.value.exit_code == 10
    return str(info.value)


def test_an_absent_device_says_so_once_and_lists_the_ports_here(tmp_path):
    """A device that does not exist: 'no such device' with what to check, the errno named once (not pyserial's
    message quoting the OS's), and the serial ports there are (or that there are none)."""
    line = _refusal(str(tmp_path / "ttyUSB9"))
    assert line.startswith(f"{tmp_path / 'ttyUSB9'}: cannot open the port: no such device: is the printer plugged in")
    assert line.count("ENOENT") == 1 and "No such file or directory" not in line and "Errno" not in line
    assert "serial ports here: " in line or "no serial port found here" in line
    assert "\n" not in line


def test_a_file_that_is_not_a_serial_port_says_so(tmp_path):
    """A plain file given as the port: 'not a serial port', the errno once."""
    plain = tmp_path / "notaport"
    plain.write_bytes(b"")
    line = _refusal(str(plain))
    assert "not a serial port" in line and line.count("ENOTTY") == 1 and "Inappropriate ioctl" not in line


@pytest.mark.parametrize("number, advice", [(13, "dialout"), (16, "busy"), (2, "plugged in")])
def test_each_errno_gives_its_advice(number, advice):
    """Permission, busy and absent each give their own advice, with the errno's symbol once."""
    line = open_failure("/dev/ttyX", OSError(number, os.strerror(number)))
    assert advice in line and line.count(os.strerror(number)) == 0 and "[E" in line


def test_a_pseudo_terminal_announces_its_rate_and_a_real_path_does_not(tmp_path):
    """announce_baud sets the pty's line speed; announced_baud reads it back on the slave's path; a connector
    without a baud takes it, one with a baud keeps its own; a path that is no pseudo-terminal announces nothing."""
    master, slave = os.openpty()
    try:
        tty.setraw(slave)
        assert announce_baud(slave, 1_000_000)
        path = os.ttyname(slave)
        assert announced_baud(path) == 1_000_000
        assert not announce_baud(slave, 123_457)  # no termios name for it: left as it was
        assert announced_baud(path) == 1_000_000
        connector = SerialConnector(path, None)
        connector.open().close()
        assert connector.baud == 1_000_000 and announced_baud(path) == 1_000_000  # opening kept the announcement
        given = SerialConnector(path, 57600)
        given.open().close()
        assert given.baud == 57600
    finally:
        os.close(slave)
        os.close(master)
    assert announced_baud(str(tmp_path / "file")) is None
    assert SerialConnector("loop://", None).open() is not None


def test_print_to_the_controller_runs_at_its_rate_without_baud(tmp_path):
    """`heoslice controller --pty` (1,000,000 baud by default) and `heoslice print --port PTY` without --baud: the
    print succeeds paced at the controller's rate (the log's 'connected' event), not at 115200."""
    stack = make_stack(tmp_path / "s", disc_masks(3))
    controller = subprocess.Popen([sys.executable, "-m", "heoslice", "controller", "--pty", "--layer-time", "0.001",
                                   "--duration", "60"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        path = controller.stdout.readline().strip()
        log = tmp_path / "print.jsonl"
        done = subprocess.run([sys.executable, "-m", "heoslice", "print", str(stack), "--port", path, "--log", log],
                              capture_output=True, text=True, timeout=60)
        assert done.returncode == 0, done.stderr
    finally:
        controller.terminate()
        _, err = controller.communicate(timeout=10)
    connected = [event for event in map(json.loads, log.read_text().splitlines()) if event["event"] == "connected"]
    assert connected and connected[0]["baud"] == 1_000_000 != DEFAULT_BAUD
    assert f"print with --port {path}" in err and "--baud" not in err.split("print with", 1)[1].splitlines()[0]
