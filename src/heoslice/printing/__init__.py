"""Printing a stack: the wire protocol, the send window, the session, ports, the job and the host link.

In the order a print uses them: ``protocol`` (pure codecs), ``job`` (a verified stack as a job),
``stream`` (the job's messages and chunking), ``window`` (the pure send-window state machine and frame
sizing), ``ports`` (what a port is, how one is opened), ``session`` (one connection: handshake, pacing),
``log`` (the print log), ``link`` (the job over sessions: progress, reconnect, resume). ``simulator/``
is the simulated controller, reached only as the ``sim://`` pyserial URL handler.
"""

from heoslice.printing.job import JobSpec, LayerSource, job_summary, pack_mask, stack_job, verified_job
from heoslice.printing.link import PrinterLink, PrintResult, Progress, print_job
from heoslice.printing.log import PrintLog, check_log_output, default_log_path
from heoslice.printing.ports import Connector, Port, SerialConnector, connector_for
from heoslice.printing.session import LinkTiming, Session
from heoslice.printing.stream import (CHUNK_HEADER, SAMPLE_LAYERS, check_from_layer, dry_run, encoded_layers,
                                      job_messages, layer_figures, next_chunk, plan_transfer)
from heoslice.printing.window import FrameSizer, SendWindow, optimal_frame_bytes

__all__ = ["JobSpec", "LayerSource", "job_summary", "pack_mask", "stack_job", "verified_job", "PrinterLink",
           "PrintResult", "Progress", "print_job", "PrintLog", "check_log_output", "default_log_path", "Connector",
           "Port", "SerialConnector", "connector_for", "LinkTiming", "Session", "CHUNK_HEADER", "SAMPLE_LAYERS",
           "check_from_layer", "dry_run", "encoded_layers", "job_messages", "layer_figures", "next_chunk",
           "plan_transfer", "FrameSizer", "SendWindow", "optimal_frame_bytes"]
