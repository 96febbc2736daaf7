"""Ports: what the host needs of a byte link (:class:`Port`), and how one is (re)opened (:class:`Connector`).

Any pyserial port satisfies :class:`Port`. :class:`SerialConnector` opens device paths and URLs through
``serial.serial_for_url``; ``sim://`` URLs are served by the simulator's pyserial URL handler, found by
package name in ``serial.protocol_handler_packages``, so this module never imports the simulator.
"""

from __future__ import annotations

from typing import Protocol

from heoslice.errors import ControllerBusyError, HeosliceError, PortError

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
    """Opens a pyserial port (device path or URL) on demand; used again to reconnect."""

    def __init__(self, port: str, baud: float):
        self.name, self.baud = port, baud

    def open(self) -> Port:
        """A fresh open port (PortError when it cannot be opened); a modelled rate (sim://) replaces ``baud``.

        Device ports are opened exclusively (pyserial's ``exclusive``: TIOCEXCL and flock), so a second
        print on this machine cannot share the controller's port (ControllerBusyError, exit 16).
        """
        import serial

        if SIM_HANDLER_PACKAGE not in serial.protocol_handler_packages:
            serial.protocol_handler_packages.append(SIM_HANDLER_PACKAGE)
        try:
            handle = serial.serial_for_url(self.name, baudrate=int(self.baud), timeout=0.005,
                                           write_timeout=WRITE_TIMEOUT_S, exclusive=True)
        except HeosliceError:
            raise
        except serial.SerialException as err:
            if "exclusively lock" in str(err):
                raise ControllerBusyError(f"{self.name}: the port is busy: another process (another print?) has "
                                          "it open; nothing was sent") from None
            raise PortError(f"{self.name}: cannot open port ({' '.join(str(err).split())})") from err
        except (OSError, ValueError) as err:
            raise PortError(f"{self.name}: cannot open port ({' '.join(str(err).split())})") from err
        self.baud = getattr(handle, "modelled_baud", self.baud)
        try:
            handle.reset_input_buffer()
        except (serial.SerialException, OSError):
            pass
        return handle

    def close(self) -> None:
        """Nothing held between connections."""


def connector_for(port: str, baud: float) -> Connector:
    """The connector for a port argument (device path, pyserial URL, ``sim://?options``)."""
    return SerialConnector(port, baud)
