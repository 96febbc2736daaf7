"""The simulated printer controller (a test double of the firmware), reached by the host only as ``sim://``.

``config`` (what it is and its faults), ``faults`` (which faults strike, and when), ``transports`` (pty, TCP,
pipe), ``controller`` (the protocol's controller side), ``protocol_sim`` (the pyserial URL handler).
"""

from heoslice.printing.simulator.config import ExecutedLayer, FaultSpec, SimConfig, sim_from_url
from heoslice.printing.simulator.controller import SimController
from heoslice.printing.simulator.transports import (FdTransport, PipePort, PipeTransport, SimConnector,
                                                    TcpServerTransport, Transport, pipe_pair)

__all__ = ["ExecutedLayer", "FaultSpec", "SimConfig", "sim_from_url", "SimController", "FdTransport", "PipePort",
           "PipeTransport", "SimConnector", "TcpServerTransport", "Transport", "pipe_pair"]
