"""``heoslice controller``: run the simulated printer controller on a pseudo-terminal or TCP port."""

from __future__ import annotations

import os
import sys
import time
import tty
import urllib.parse

import click

from heoslice.cli.common import echo_json, json_option, plural
from heoslice.errors import InputError
from heoslice.printing.ports import announce_baud


@click.command("controller", epilog="""\b
Examples:
  heoslice controller --pty                      # prints e.g. /dev/pts/5
  heoslice print vase_stack/ --port /dev/pts/5   # in another terminal, at the modelled rate
  heoslice controller --listen 127.0.0.1:7000 --layer-time 0.05
  heoslice controller --pty --set byte_error_rate=1e-3 --set reset_at_layer=40 --seed 3
  heoslice controller --pty --real-pacing        # a 115200-baud UART and a 0.2 s head
\b
By default the link is modelled fast (1,000,000 baud, 2 ms a layer) so a dry run takes
seconds; --baud and --layer-time override it. On --pty the modelled rate is announced as
the terminal's line speed, so `print` paces itself to it without --baud (a rate termios
cannot name is not announced: give print the same --baud). Connections, jobs, layers, aborts, pauses,
resumes and resets are logged on stderr (-q: quiet).
--set takes any field of SimConfig or FaultSpec (heoslice.printing.simulator), e.g.
frame_drop_rate, frame_dup_rate, ack_loss_rate, disconnect_at_layer, dead_at_layer,
fail_at_layer, stop_reading_at_layer, claim_completed, rx_buffer, max_payload, version,
features (0: no SACK, plain go-back-N). Every value is checked.
Ctrl-C, SIGTERM, SIGHUP or the end of --duration stop it normally (exit 0).
""")
@click.option("--pty", "use_pty", is_flag=True, help="Serve on a new pseudo-terminal and print its path.")
@click.option("--listen", default=None, metavar="HOST:PORT",
              help="Serve on TCP (connect with --port socket://HOST:PORT).")
@click.option("--baud", type=click.IntRange(min=1), default=None,
              help="Modelled link rate, bits/s [default: 1000000, or 115200 with --real-pacing].")
@click.option("--layer-time", type=click.FloatRange(min=0), default=None,
              help="Head time per layer, s [default: 0.002, or 0.2 with --real-pacing].")
@click.option("--real-pacing", is_flag=True, help="Model a 115200-baud UART and a 0.2 s head.")
@click.option("--time-scale", type=click.FloatRange(min=0, min_open=True), default=1.0, show_default=True,
              help="Multiply modelled durations (0.01 runs 100x faster).")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Seed of the fault generator (boot ids are fresh at every start).")
@click.option("--set", "settings", multiple=True, metavar="NAME=VALUE", help="Any simulator or fault field.")
@click.option("--duration", type=click.FloatRange(min=0), default=None,
              help="Stop after this many seconds [default: until Ctrl-C].")
@click.option("-q", "--quiet", is_flag=True, help="Log nothing on stderr.")
@json_option
def controller(use_pty: bool, listen: str | None, baud: int | None, layer_time: float | None, real_pacing: bool,
               time_scale: float, seed: int, settings: tuple[str, ...], duration: float | None,
               quiet: bool, as_json: bool) -> None:
    """Run the simulated controller so a pipeline can be dry-run end to end without hardware."""
    from heoslice.printing.simulator import (
        FdTransport,
        SimController,
        TcpServerTransport,
        sim_from_url,
    )

    if use_pty == (listen is not None):
        raise click.UsageError("give exactly one of --pty and --listen HOST:PORT")
    pairs = [("pace", "real" if real_pacing else "fast"), ("time_scale", repr(time_scale)), ("seed", str(seed))]
    pairs += [("baud", str(baud))] if baud is not None else []
    pairs += [("layer_time_s", repr(layer_time))] if layer_time is not None else []
    for item in settings:
        name, sep, value = item.partition("=")
        if not sep:
            raise InputError(f"--set {item!r}: expected NAME=VALUE")
        pairs.append((name.strip(), value.strip()))
    url = "sim://?" + urllib.parse.urlencode(pairs)
    try:
        config, faults = sim_from_url(url)
    except Exception as err:  # PortError names the URL; say it as an option problem
        raise InputError(str(err).replace(url + ": ", "--set: ")) from err

    def log(text: str) -> None:
        print(f"controller: {text}", file=sys.stderr, flush=True)

    sim = SimController(config, faults, log=None if quiet else log)
    slave, announced = None, False
    if use_pty:
        master, slave = os.openpty()
        tty.setraw(slave)
        announced = announce_baud(slave, config.baud / config.time_scale)
        transport = FdTransport(master)
        where = os.ttyname(slave)
    else:
        host, _, port = listen.rpartition(":")
        if not (port.isdigit() and int(port) <= 65535):
            raise InputError(f"--listen {listen}: expected HOST:PORT with a port from 0 to 65535 (0: any free one)")
        try:
            transport = TcpServerTransport(host or "127.0.0.1", int(port))
        except OSError as err:
            raise InputError(f"--listen {listen}: cannot listen ({err.strerror or err})") from err
        where = "socket://{}:{}".format(*transport.address)
    if as_json:
        echo_json({"port": where, "ok": True, "baud": config.baud, "boot_id": f"{sim.boot_id:08x}"})
    else:
        click.echo(where)
    if not quiet:
        log(f"serving on {where}: {config.baud} baud, {config.layer_time_s:g} s a layer, boot id {sim.boot_id:08x}; "
            f"print with --port {where}" + ("" if announced else f" --baud {config.baud}"))
    sim.start(transport)
    try:
        end = None if duration is None else time.monotonic() + duration
        while end is None or time.monotonic() < end:
            time.sleep(0.1)
    except KeyboardInterrupt:
        pass
    finally:
        sim.stop()
        if slave is not None:
            os.close(slave)
    layers = sim.executed_layers()
    if not quiet:
        click.echo(f"controller stopped: {plural(len(layers), 'layer')} executed"
                   + (f" ({layers[0]}..{layers[-1]})" if layers else ""), err=True)
