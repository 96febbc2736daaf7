"""``heoslice controller``: run the simulated printer controller on a pseudo-terminal or TCP port."""

from __future__ import annotations

import os
import time
import tty
import urllib.parse

import click

from heoslice.errors import InputError


@click.command("controller", epilog="""\b
Examples:
  heoslice controller --pty                      # prints e.g. /dev/pts/5
  heoslice print vase_stack/ --port /dev/pts/5   # in another terminal
  heoslice controller --listen 127.0.0.1:7000 --layer-time 0.05
  heoslice controller --pty --set byte_error_rate=1e-3 --set reset_at_layer=40 --seed 3
  heoslice controller --pty --time-scale 0.01    # 100x faster than real time
\b
--set takes any field of SimConfig or FaultSpec (heoslice.printing.simulator), e.g.
frame_drop_rate, frame_dup_rate, ack_loss_rate, disconnect_at_layer, dead_at_layer,
fail_at_layer, rx_buffer, max_payload, version, features (0: no SACK, plain go-back-N).
""")
@click.option("--pty", "use_pty", is_flag=True, help="Serve on a new pseudo-terminal and print its path.")
@click.option("--listen", default=None, metavar="HOST:PORT",
              help="Serve on TCP (connect with --port socket://HOST:PORT).")
@click.option("--baud", type=click.IntRange(min=1), default=115200, show_default=True,
              help="Modelled link rate, bits/s.")
@click.option("--layer-time", type=click.FloatRange(min=0), default=0.2, show_default=True,
              help="Head time per layer, s.")
@click.option("--time-scale", type=click.FloatRange(min=0, min_open=True), default=1.0, show_default=True,
              help="Multiply modelled durations (0.01 runs 100x faster).")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the fault generator and boot ids.")
@click.option("--set", "settings", multiple=True, metavar="NAME=VALUE", help="Any simulator or fault field.")
@click.option("--duration", type=click.FloatRange(min=0), default=None,
              help="Stop after this many seconds [default: until Ctrl-C].")
def controller(use_pty: bool, listen: str | None, baud: int, layer_time: float, time_scale: float, seed: int,
               settings: tuple[str, ...], duration: float | None) -> None:
    """Run the simulated controller so a pipeline can be dry-run end to end without hardware."""
    from heoslice.printing.simulator import FdTransport, SimController, TcpServerTransport, sim_from_url

    if use_pty == (listen is not None):
        raise click.UsageError("give exactly one of --pty and --listen HOST:PORT")
    pairs = [("baud", str(baud)), ("layer_time_s", repr(layer_time)), ("time_scale", repr(time_scale)),
             ("seed", str(seed))]
    for item in settings:
        name, sep, value = item.partition("=")
        if not sep:
            raise InputError(f"--set {item!r}: expected NAME=VALUE")
        pairs.append((name.strip(), value.strip()))
    try:
        config, faults = sim_from_url("sim://?" + urllib.parse.urlencode(pairs))
    except Exception as err:  # PortError names the URL; say it as an option problem
        raise InputError(str(err).replace("sim://?" + urllib.parse.urlencode(pairs) + ": ", "--set: ")) from err
    sim = SimController(config, faults)
    slave = None
    if use_pty:
        master, slave = os.openpty()
        tty.setraw(slave)
        transport = FdTransport(master)
        where = os.ttyname(slave)
    else:
        host, _, port = listen.rpartition(":")
        try:
            transport = TcpServerTransport(host or "127.0.0.1", int(port))
        except (ValueError, OSError) as err:
            raise InputError(f"--listen {listen}: cannot listen ({err})") from err
        where = "socket://{}:{}".format(*transport.address)
    click.echo(where)
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
    click.echo(f"controller stopped: {len(layers)} layer(s) executed"
               + (f" ({layers[0]}..{layers[-1]})" if layers else ""), err=True)
