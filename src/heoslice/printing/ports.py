"""Ports: what the host needs of a byte link (:class:`Port`), and how one is (re)opened (:class:`Connector`).

Any pyserial port satisfies :class:`Port`. :class:`SerialConnector` opens device paths and URLs through
``serial.serial_for_url``; ``sim://`` URLs are served by the simulator's pyserial URL handler, found by
package name in ``serial.protocol_handler_packages``, so this module never imports the simulator.

A pseudo-terminal has no wire, so its line speed is free to carry a message: ``heoslice controller --pty``
sets it to the rate it models (:func:`announce_baud`) and a print given no ``--baud`` paces its writes to that
rate (:func:`announced_baud`); a real device is paced at ``--baud`` [default: :data:`DEFAULT_BAUD`].
"""

from __future__ import annotations

import errno
import os
import re
from typing import Protocol

from heoslice.errors import ControllerBusyError, HeosliceError, PortError

#: The line rate a print paces its writes to when neither --baud nor a simulated controller's terminal says.
DEFAULT_BAUD = 115200
#: Device paths of pseudo-terminals (Linux's /dev/pts/N, macOS's /dev/ttysNNN): where a line speed is an
#: announcement rather than a wire's setting.
PSEUDO_TERMINAL = re.compile(r"^/dev/(pts/\d+|ttys\d+)$")
_ABSENT = "no such device: is the printer plugged in and powered, and is this its port?"
_DENIED = ("permission denied: add your user to the group owning the device (on Linux usually 'dialout': "
           "sudo usermod -aG dialout $USER, then log in again)")
#: Why a port would not open, by errno -> what it means to the user and what to do (the errno's symbol follows,
#: once: not the OS's text quoted inside pyserial's).
OPEN_ADVICE = {
    errno.ENOENT: _ABSENT, errno.ENODEV: _ABSENT, errno.ENXIO: _ABSENT,
    errno.EACCES: _DENIED, errno.EPERM: _DENIED,
    errno.EBUSY: "the device is busy: another program (a serial monitor, another print) has it open; close it",
    errno.ENOTTY: "not a serial port (a plain file or another kind of device)",
    errno.EIO: "input/output error: the device was unplugged or is failing; replug it",
}

#: Where pyserial looks for ``protocol_<scheme>`` URL handlers beyond its own (``sim://``).
SIM_HANDLER_PACKAGE = "heoslice.printing.simulator"
#: A write blocked this long means the peer stopped reading: the link is treated as lost.
WRITE_TIMEOUT_S = 0.5


class Port(Protocol):
    """The subset of pyserial's ``Serial`` the host uses."""

    timeout: float | None

    @property
    def in_waiting(self) -> int: ...

    def read(self, size: int = 1) -> bytes: ...

    def write(self, data: bytes) -> int | None: ...

    def reset_input_buffer(self) -> None: ...

    def close(self) -> None: ...


class Connector(Protocol):
    """Opens a fresh :class:`Port` on demand (again after a link loss); ``baud`` paces writes (None: unpaced)."""

    name: str
    baud: float | None

    def open(self) -> Port: ...

    def close(self) -> None: ...


class SerialConnector:
    """Opens a pyserial port (device path or URL) on demand; used again to reconnect. ``baud`` None: the rate a
    simulated controller's pseudo-terminal announces, else DEFAULT_BAUD (fixed at the first open)."""

    def __init__(self, port: str, baud: float | None):
        self.name, self.baud = port, baud

    def open(self) -> Port:
        """A fresh open port (PortError when it cannot be opened); a modelled rate (sim://) replaces ``baud``.

        Device ports are opened exclusively (pyserial's ``exclusive``: TIOCEXCL and flock), so a second
        print on this machine cannot share the controller's port (ControllerBusyError, exit 16).
        """
        import serial

        if SIM_HANDLER_PACKAGE not in serial.protocol_handler_packages:
            serial.protocol_handler_packages.append(SIM_HANDLER_PACKAGE)
        if self.baud is None:
            self.baud = announced_baud(self.name) or DEFAULT_BAUD
        try:
            handle = serial.serial_for_url(self.name, baudrate=int(self.baud), timeout=0.005,
                                           write_timeout=WRITE_TIMEOUT_S, exclusive=True)
        except HeosliceError:
            raise
        except serial.SerialException as err:
            if "exclusively lock" in str(err):
                raise ControllerBusyError(f"{self.name}: the port is busy: another process (another print?) has "
                                          "it open; nothing was sent") from None
            raise PortError(open_failure(self.name, err)) from err
        except (OSError, ValueError) as err:
            raise PortError(open_failure(self.name, err)) from err
        self.baud = getattr(handle, "modelled_baud", self.baud)
        try:
            handle.reset_input_buffer()
        except (serial.SerialException, OSError):
            pass
        return handle

    def close(self) -> None:
        """Nothing held between connections."""


def open_failure(port: str, err: BaseException) -> str:
    """The one line for a port that would not open: what the errno means to the user and what to do, the errno's
    own text once, and the serial ports this machine has."""
    number = getattr(err, "errno", None)
    cause = err.__cause__ or err.__context__
    if not isinstance(number, int) and cause is not None and cause.args and isinstance(cause.args[0], int):
        number = cause.args[0]  # pyserial wraps termios.error (errno, text) without an errno of its own
    if isinstance(number, int) and number in OPEN_ADVICE:
        detail = f"{OPEN_ADVICE[number]} [{errno.errorcode.get(number, number)}]"
    else:
        detail = re.sub(r"\[Errno \d+\]\s*", "", " ".join(str(err).split())) or type(err).__name__
    return f"{port}: cannot open the port: {detail}; {ports_here()}"


def ports_here() -> str:
    """'serial ports here: /dev/ttyACM0 (Arduino Due), ...' (at most 6) or 'no serial port found here'."""
    try:
        from serial.tools import list_ports

        found = sorted(list_ports.comports(), key=lambda port: port.device)
    except Exception:  # noqa: BLE001 - listing is advice only; an error in it must not hide the port's
        found = []
    if not found:
        return "no serial port found here (heoslice controller --pty makes a simulated one)"
    named = [port.device + (f" ({port.description})" if port.description not in ("", "n/a", port.device) else "")
             for port in found[:6]]
    return "serial ports here: " + ", ".join(named) + (", ..." if len(found) > 6 else "")


def terminal_speeds() -> dict[int, int]:
    """termios speed constant -> bits/s, for the rates this platform's termios names (B9600 ... B4000000)."""
    import termios

    return {getattr(termios, name): int(name[1:]) for name in dir(termios) if re.fullmatch(r"B\d+", name)
            and int(name[1:]) > 0}


def announce_baud(fd: int, baud: float) -> bool:
    """Set the pseudo-terminal ``fd``'s line speed to ``baud`` (a simulated controller's modelled rate) when
    termios names that rate; whether it was announced."""
    import termios

    constant = {rate: code for code, rate in terminal_speeds().items()}.get(int(baud)) if baud == int(baud) else None
    if constant is None:
        return False
    attributes = termios.tcgetattr(fd)
    attributes[4] = attributes[5] = constant
    termios.tcsetattr(fd, termios.TCSANOW, attributes)
    return True


def announced_baud(port: str) -> int | None:
    """The rate the pseudo-terminal ``port`` announces (its line speed), or None: not a pseudo-terminal, or it
    cannot be read."""
    if not PSEUDO_TERMINAL.match(os.path.realpath(port)):
        return None
    import termios

    try:
        fd = os.open(port, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    except OSError:
        return None
    try:
        return terminal_speeds().get(termios.tcgetattr(fd)[5])
    except termios.error:
        return None
    finally:
        os.close(fd)


def connector_for(port: str, baud: float | None) -> Connector:
    """The connector for a port argument (device path, pyserial URL, ``sim://?options``)."""
    return SerialConnector(port, baud)
