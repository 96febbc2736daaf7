"""``heoslice print``: verify a stack, then stream its layers to the printer's controller."""

from __future__ import annotations

import json
from pathlib import Path

import click

from heoslice.cli.common import progress_bar
from heoslice.locks import hold_stack
from heoslice.printing.ports import DEFAULT_BAUD
from heoslice.printing import SAMPLE_LAYERS, dry_run, job_summary, stack_job
from heoslice.stack import check_input_path


@click.command("print", epilog="""\b
Examples:
  heoslice print vase_stack/ --port /dev/ttyUSB0
  heoslice print vase_stack/ --port socket://192.168.1.40:7000 --baud 1000000
  heoslice print vase_stack/ --port /dev/ttyACM0 --from-layer 120   # after a controller reset
  heoslice print vase_stack/ --port /dev/ttyACM0 --resume            # continue an interrupted job
  heoslice print vase_stack/ --port /dev/ttyACM0 --restart           # abort it, start at layer 0
  heoslice print vase_stack/ --port /dev/pts/5                       # `heoslice controller --pty`, at its rate
  heoslice print vase_stack/ --port sim://                           # built-in simulator, fast
  heoslice print vase_stack/ --port 'sim://?pace=real'               # ... at 115200 baud, 0.2 s a layer
  heoslice print vase_stack/ --dry-run                               # verify, estimate the transfer
  heoslice print vase_stack/ --dry-run --exact                       # ... encoding every layer
""")
@click.argument("stack", type=click.Path(path_type=Path))
@click.option("-p", "--port", default=None,
              help="Device path or pyserial URL (socket://HOST:PORT, rfc2217://..., sim://?OPTIONS).")
@click.option("--baud", type=click.IntRange(min=1), default=None,
              help="Link rate, bits/s (also paces writes on URLs that ignore it) [default: the rate `heoslice "
                   "controller --pty` announces on its terminal, else 115200].")
@click.option("--from-layer", type=click.IntRange(min=0), default=None,
              help="Start at this layer (after a controller reset) instead of 0 or the controller's resume point.")
@click.option("--resume", is_flag=True, help="Continue the controller's unfinished job of this stack.")
@click.option("--restart", is_flag=True, help="Abort the controller's unfinished job and print from layer 0.")
@click.option("--dry-run", is_flag=True,
              help="Verify every layer as a print would and size the transfer; open no port. The frames and wire "
                   f"bytes are estimated from {SAMPLE_LAYERS} layers spread evenly over the stack (every layer of a "
                   "smaller one), scaled by the bytes each layer's files take: within 1 % of --exact on the "
                   "benchmark stacks and in the tests; the raw bytes are exact.")
@click.option("--exact", is_flag=True,
              help="With --dry-run: encode every layer as the print would, for the exact frames and wire bytes "
                   "(deflating every chunk: about as long as slicing the stack took).")
@click.option("--log", "log_path", type=click.Path(path_type=Path), default=None,
              help="Print log, JSON lines [default: STACK.print-log.jsonl beside the stack].")
@click.option("--max-payload", type=click.IntRange(80, 4096), default=1024, show_default=True,
              help="Largest frame payload offered to the controller, bytes.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary instead of text.")
def print_cmd(stack: Path, port: str | None, baud: int | None, from_layer: int | None, resume: bool, restart: bool,
              dry_run: bool, exact: bool, log_path: Path | None, max_payload: int, as_json: bool) -> None:
    """Verify STACK (manifest, sha256 of every file, paths inside it), then print it on PORT.
    A stack that cannot print is refused in one line, --dry-run too: an RGBA preview stack
    (slice --rgba) or one whose every layer is empty.

    Each layer's solid mask is sent as channel 0 (bit-packed rows), droplet masks as
    channels 1.. when the stack has them. Progress shows on a terminal; Ctrl-C sends
    ABORT to the controller and exits cleanly, as do SIGTERM and SIGHUP. Every executed
    layer is logged. The stack is held for the whole print: a slice into it is refused.
    A controller holding an unfinished job is never continued or overwritten silently.
    """
    check_input_path(stack)
    if exact and not dry_run:
        raise click.UsageError("--exact sizes a dry run: give it with --dry-run")
    if dry_run:
        _dry_run(stack, baud, max_payload, from_layer, exact, as_json)
        return
    if not port:
        raise click.UsageError("--port is required (or use --dry-run)")
    if resume and restart:
        raise click.UsageError("--resume and --restart exclude each other")
    if restart and from_layer is not None:
        raise click.UsageError("--restart starts at layer 0; it excludes --from-layer")
    with hold_stack(stack, "printing it"):
        _print(stack, port, baud, from_layer, resume, restart, log_path, max_payload, as_json)


def _dry_run(stack: Path, baud: int | None, max_payload: int, from_layer: int | None, exact: bool,
             as_json: bool) -> None:
    """Verify and size the transfer (estimated from a sample of layers unless ``exact``); no port."""
    baud = baud or DEFAULT_BAUD
    with progress_bar("verifying", enabled=not as_json) as verifying, \
            progress_bar("sizing", enabled=not as_json) as sizing:
        job, plan = dry_run(stack, baud=baud, max_payload=max_payload, from_layer=from_layer or 0,
                            sample=None if exact else SAMPLE_LAYERS, verifying=verifying, sizing=sizing)
        summary = {"stack": str(stack), "ok": True, "job_id": f"{job.job_id:08x}", **plan}
    if as_json:
        click.echo(json.dumps(summary))
        return
    about, source = "", ""
    if summary["estimated"]:
        about = "about "
        source = (f" (estimated from {summary['layers_encoded']} of {summary['layers']} layers; --exact encodes "
                  "every layer)")
    click.echo(f"{stack}: verified; {job_summary(job)}\n"
               f"would send {about}{summary['frames']} frames, {about}{summary['wire_bytes']} bytes "
               f"({summary['raw_bytes']} raw), about {summary['seconds_at_baud']:.1f} s at {baud} baud{source}")


def _print(stack: Path, port: str, baud: int | None, from_layer: int | None, resume: bool, restart: bool,
           log_path: Path | None, max_payload: int, as_json: bool) -> None:
    """Print the held stack and report."""
    from heoslice.printing import Progress, check_log_output, default_log_path, print_job

    log_path = log_path or default_log_path(stack)
    check_log_output(log_path, inputs=(stack,))
    with progress_bar("verifying", enabled=not as_json) as verifying:
        job, get_layer = stack_job(stack, verifying)
    with progress_bar("printing", enabled=not as_json) as update:
        def progress(state: Progress) -> None:
            rate = state.bytes_sent / state.elapsed_s if state.elapsed_s > 0 else 0.0
            update(state.layers_done, state.layers_total, f"layer {state.layer}, {rate / 1000:.1f} kB/s")

        result = print_job(port, job, get_layer, baud=baud, from_layer=from_layer, resume=resume, restart=restart,
                           log_path=log_path, on_progress=progress, max_payload=max_payload,
                           label=f"stack {stack}", name=Path(stack).resolve().name)
    if as_json:
        click.echo(json.dumps({"stack": str(stack), "ok": True, "port": port, "log": str(log_path),
                               "job_id": f"{job.job_id:08x}",
                               **{**result.__dict__, "boot_id": f"{result.boot_id:08x}"}}))
        return
    rate = result.bytes_sent / result.elapsed_s if result.elapsed_s > 0 else 0.0
    click.echo(f"{stack}: printed layers {result.first_layer}..{result.last_completed} on {port} "
               f"in {result.elapsed_s:.1f} s ({result.bytes_sent} bytes, {rate / 1000:.1f} kB/s, "
               f"{result.frames_retransmitted} frames resent); log: {log_path}")
