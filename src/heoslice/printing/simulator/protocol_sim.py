"""The ``sim://`` URL handler for pyserial: ``serial.serial_for_url('sim://?baud=...')`` opens a simulated controller.

pyserial finds this module as ``protocol_sim`` in a package listed in ``serial.protocol_handler_packages``
(the host adds ``heoslice.printing.simulator`` there), so the host opens ``sim://`` like any other URL
and never imports the simulator. One controller lives per distinct URL and process, started at its
first open and kept running between opens, so a reconnect finds the same controller (and boot id),
as with a powered printer.
"""

from __future__ import annotations

import threading

import serial

from heoslice.errors import PortError
from heoslice.printing.simulator.config import sim_from_url
from heoslice.printing.simulator.controller import SimController
from heoslice.printing.simulator.transports import pipe_pair

_CONTROLLERS: dict[str, SimController] = {}
_REGISTRY_LOCK = threading.Lock()


def controller_for(url: str) -> SimController:
    """The running controller behind ``url`` in this process, started on first use (PortError on a bad option)."""
    with _REGISTRY_LOCK:
        controller = _CONTROLLERS.get(url)
        if controller is None:
            config, faults = sim_from_url(url)
            controller = _CONTROLLERS[url] = SimController(config, faults)
            controller.start()
        return controller


class Serial(serial.SerialBase):
    """A pyserial port whose other end is a simulated controller on a thread of this process."""

    def open(self) -> None:
        """Connect a fresh pipe to the URL's controller; PortError (one line) on a bad sim:// option."""
        if self._port is None:
            raise serial.SerialException("port must be configured before it can be used")
        if self.is_open:
            raise serial.SerialException("port already open")
        controller = controller_for(self._port)
        self._pipe, transport = pipe_pair(self._port)
        controller.attach(transport)
        #: The link rate the controller models, bits/s: what the host paces its writes to.
        self.modelled_baud = controller.config.baud / max(controller.config.time_scale, 1e-12)
        self.is_open = True

    def close(self) -> None:
        if self.is_open:
            self._pipe.close()
            self.is_open = False

    def _reconfigure_port(self, force_update: bool = False) -> None:
        """Nothing to configure: the modelled rate comes from the URL."""

    def from_url(self, url: str) -> str:
        return url

    @property
    def in_waiting(self) -> int:
        return self._pipe.in_waiting

    def read(self, size: int = 1) -> bytes:
        self._pipe.timeout = self._timeout
        return self._pipe.read(size)

    def write(self, data: bytes) -> int:
        return self._pipe.write(data)

    def reset_input_buffer(self) -> None:
        self._pipe.reset_input_buffer()

    def reset_output_buffer(self) -> None:
        """Nothing is buffered on the host side."""


__all__ = ["Serial", "controller_for", "PortError"]
