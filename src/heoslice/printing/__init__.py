"""Printing a stack: the wire protocol, the send window, the session, ports, the job and the host link.

In the order a print uses them: ``protocol`` (pure codecs), ``job`` (a verified stack as a job),
``stream`` (the job's messages and chunking), ``window`` (the pure send-window state machine and frame
sizing), ``ports`` (what a port is, how one is opened), ``session`` (one connection: handshake, pacing),
``log`` (the print log), ``link`` (the job over sessions: progress, reconnect, resume). ``simulator/``
is the simulated controller, reached only as the ``sim://`` pyserial URL handler.

The names below are loaded on first use (PEP 562), not when the package is imported: a dry run loads the job
and the stream, not the link, its session and its ports.
"""

from __future__ import annotations

from heoslice.lazy import lazy_exports

#: Each module of this package -> the public names it defines.
_MODULES = {
    "job": ("JobSpec", "LayerSource", "job_summary", "pack_mask", "stack_job", "verified_job"),
    "link": ("PrinterLink", "PrintResult", "Progress", "print_job"),
    "log": ("PrintLog", "check_log_output", "default_log_path"),
    "ports": ("Connector", "Port", "SerialConnector", "connector_for"),
    "session": ("LinkTiming", "Session"),
    "stream": ("CHUNK_HEADER", "SAMPLE_LAYERS", "check_from_layer", "dry_run", "encoded_layers", "job_messages",
               "layer_figures", "next_chunk", "plan_transfer"),
    "window": ("FrameSizer", "SendWindow", "optimal_frame_bytes"),
}

__all__, __getattr__, __dir__ = lazy_exports(__name__, _MODULES)
