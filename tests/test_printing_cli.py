"""`heoslice print` and `heoslice controller` as a lab runs them: subprocesses, a pty or TCP controller, signals.

Exactly-once is checked against what the simulated head executed (the controller's own stderr log,
one line per executed layer), never against the host's log.
"""

from __future__ import annotations

import json
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from printing_jobs import disc_masks, make_stack

from heoslice.errors import StackBusyError
from heoslice.locks import hold_stack

HEOSLICE = [sys.executable, "-m", "heoslice"]


class Controller:
    """`heoslice controller` in a subprocess; a thread collects its stderr (the head's log)."""

    def __init__(self, *args: str, listen: str | None = None, layer_time: float = 0.002):
        where = ["--listen", listen] if listen else ["--pty"]
        self.proc = subprocess.Popen([*HEOSLICE, "controller", *where, "--layer-time", repr(layer_time), *args],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.port = self.proc.stdout.readline().strip()
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.stderr:
            self.lines.append(line.rstrip("\n"))

    def executed(self, job: str | None = None) -> list[int]:
        """Layers the head executed, in order (of job ``job``, 8 hex digits, when given)."""
        out = []
        for line in list(self.lines):
            found = re.fullmatch(r"controller: layer (\d+) executed \(job ([0-9a-f]{8})\)", line)
            if found and (job is None or found.group(2) == job):
                out.append(int(found.group(1)))
        return out

    def boot_id(self) -> str:
        self.wait_for("boot id")
        return re.search(r"boot id ([0-9a-f]{8})", "\n".join(self.lines)).group(1)

    def wait_for(self, text: str, timeout: float = 10.0) -> None:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if any(text in line for line in list(self.lines)):
                return
            time.sleep(0.02)
        raise AssertionError(f"controller never logged {text!r}: {self.lines[-5:]}")

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
        self._reader.join(5)
        self.proc.stdout.close()


@pytest.fixture
def controller():
    started: list[Controller] = []

    def make(*args, **kwargs) -> Controller:
        started.append(Controller(*args, **kwargs))
        return started[-1]

    yield make
    for c in started:
        c.stop()


def _default_signals() -> None:
    """In the child: SIGINT as a terminal delivers it, even when the test runner ignores it."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def run(*args, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([*HEOSLICE, *map(str, args)], capture_output=True, text=True, timeout=timeout)


def start_print(stack: Path, port: str, *args) -> subprocess.Popen:
    return subprocess.Popen([*HEOSLICE, "print", str(stack), "--port", port, "--baud", "1000000", *map(str, args)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_default_signals)


def events(log: Path) -> list[dict]:
    return [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []


def runs(log: Path) -> list[list[dict]]:
    """The log split into runs (each from its `start` event)."""
    out: list[list[dict]] = []
    for record in events(log):
        if record["event"] == "start":
            out.append([])
        out[-1].append(record)
    return out


def wait_layers(log: Path, count: int, timeout: float = 20.0) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if sum(r["event"] == "layer" for r in (runs(log) or [[]])[-1]) >= count:
            return
        time.sleep(0.02)
    raise AssertionError(f"fewer than {count} layers logged in {log}")


def job_of(log: Path) -> str:
    return events(log)[0]["job_id"]


def one_line(stderr: str) -> str:
    assert stderr.count("\n") == 1 and "Traceback" not in stderr, stderr
    return stderr


def assert_true_log(run_events: list[dict], layers: range) -> None:
    """One layer event per layer this run executed, bytes > 0, all after `connected`."""
    kinds = [r["event"] for r in run_events]
    connected = kinds.index("connected")
    layer_events = [r for r in run_events if r["event"] == "layer"]
    assert [r["layer"] for r in layer_events] == list(layers)
    assert all(r["bytes"] > 0 for r in layer_events)
    assert all(i > connected for i, kind in enumerate(kinds) if kind == "layer")


@pytest.mark.slow  # among the slowest (README "Development"): waits on a paced simulator
def test_two_jobs_in_a_row_give_two_true_logs(tmp_path, controller):
    """Two stacks, then the first again, on one running controller: three true logs, each layer executed once per
    run; the dry run, the log and the controller show the job id the same way (8 hex digits)."""
    ctl = controller()
    a = make_stack(tmp_path / "a", disc_masks(12))
    b = make_stack(tmp_path / "b", disc_masks(9, 48, 32))
    for stack in (a, b, a):
        result = run("print", stack, "--port", ctl.port, "--baud", 1000000)
        assert result.returncode == 0, result.stderr
    log_a, log_b = tmp_path / "a.print-log.jsonl", tmp_path / "b.print-log.jsonl"
    first, again = runs(log_a)
    assert_true_log(first, range(12))
    assert_true_log(again, range(12))
    assert_true_log(runs(log_b)[0], range(9))
    assert ctl.executed(job_of(log_a)) == list(range(12)) * 2 and ctl.executed(job_of(log_b)) == list(range(9))
    dry = run("print", a, "--dry-run")
    assert f"job id {job_of(log_a)}" in dry.stdout
    assert any(f"job {job_of(log_b)}: begun at layer 0" in line for line in ctl.lines)


@pytest.mark.parametrize("signum, option", [(signal.SIGTERM, "--resume"), (signal.SIGHUP, "--restart"),
                                            (signal.SIGINT, "--resume")])
@pytest.mark.slow  # among the slowest (README "Development"): waits on a paced simulator
def test_signal_aborts_and_a_rerun_needs_resume_or_restart(tmp_path, controller, signum, option):
    """SIGTERM, SIGHUP and SIGINT mid-job send ABORT, log `interrupted` and exit 128 + signum with one line naming
    the last layer the head really completed; a plain rerun is refused naming --resume and --restart; --resume
    continues so every layer executes exactly once, --restart prints from layer 0 again."""
    ctl = controller(layer_time=0.05)
    stack = make_stack(tmp_path / "s", disc_masks(20))
    log = tmp_path / "s.print-log.jsonl"
    proc = start_print(stack, ctl.port)
    wait_layers(log, 3)
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == 128 + signum
    line = one_line(err)
    assert "interrupted" in line and "ABORT sent" in line
    ctl.wait_for("abort")
    time.sleep(0.2)
    job = job_of(log)
    done = ctl.executed(job)
    assert done == list(range(len(done))) and f"last completed layer {done[-1]})" in line
    assert events(log)[-1]["event"] == "interrupted"
    plain = run("print", stack, "--port", ctl.port, "--baud", 1000000)
    assert plain.returncode == 17 and "--resume" in plain.stderr and "--restart" in one_line(plain.stderr)
    assert ctl.executed(job) == done
    rerun = run("print", stack, "--port", ctl.port, "--baud", 1000000, option)
    assert rerun.returncode == 0, rerun.stderr
    if option == "--resume":
        assert ctl.executed(job) == list(range(20))
        assert_true_log(runs(log)[-1], range(done[-1] + 1, 20))
    else:
        assert ctl.executed(job) == done + list(range(20))
        assert_true_log(runs(log)[-1], range(20))
        assert "restart" in [r["event"] for r in runs(log)[-1]]


@pytest.mark.slow  # among the slowest (README "Development"): waits on a paced simulator
@pytest.mark.parametrize("after_layers", [1, 8])
def test_kill_9_then_reruns_execute_each_layer_once(tmp_path, controller, after_layers):
    """After kill -9 of a print: a rerun at once is refused as busy (the dead host's lease runs 3 s); then a plain
    rerun and a --from-layer (last logged + 1) below what the controller holds are refused; --resume completes
    with every layer executed exactly once by the head."""
    ctl = controller("--set", "rx_buffer=400", layer_time=0.05)
    stack = make_stack(tmp_path / "s", disc_masks(20))
    log = tmp_path / "s.print-log.jsonl"
    proc = start_print(stack, ctl.port)
    wait_layers(log, after_layers)
    proc.kill()
    proc.communicate(timeout=10)
    busy = run("print", stack, "--port", ctl.port, "--baud", 1000000)
    assert busy.returncode == 16 and "busy" in one_line(busy.stderr) and "('s')" in busy.stderr
    time.sleep(3.2)
    logged = [r["layer"] for r in events(log) if r["event"] == "layer"]
    plain = run("print", stack, "--port", ctl.port, "--baud", 1000000)
    assert plain.returncode == 17 and "--resume" in one_line(plain.stderr)
    other = run("print", make_stack(tmp_path / "c", disc_masks(3)), "--port", ctl.port, "--baud", 1000000)
    assert other.returncode == 17 and "another stack, 's'" in one_line(other.stderr) and "--restart" in other.stderr
    below = run("print", stack, "--port", ctl.port, "--baud", 1000000, "--from-layer", logged[-1] + 1)
    assert below.returncode == 17 and "--from-layer" in one_line(below.stderr)
    resumed = run("print", stack, "--port", ctl.port, "--baud", 1000000, "--resume")
    assert resumed.returncode == 0, resumed.stderr
    assert ctl.executed(job_of(log)) == list(range(20))


@pytest.mark.slow  # among the slowest (README "Development"): waits on a paced simulator
def test_two_concurrent_prints_and_the_stack_lock(tmp_path, controller):
    """A second print to a busy controller (its port held exclusively) is refused with one line (exit 16) and the
    first completes exactly once;
    while a print runs its stack is held (a slice's lock is refused, a second print of it exits 18); a SIGKILLed
    print leaves no stale lock."""
    ctl = controller("--set", "rx_buffer=400", layer_time=0.1)
    a = make_stack(tmp_path / "a", disc_masks(40))
    b = make_stack(tmp_path / "b", disc_masks(5, 48, 32))
    proc = start_print(a, ctl.port)
    wait_layers(tmp_path / "a.print-log.jsonl", 1)
    second = run("print", b, "--port", ctl.port, "--baud", 1000000)
    assert second.returncode == 16 and "busy" in one_line(second.stderr)
    with pytest.raises(StackBusyError):
        with hold_stack(a, "slicing into it"):
            pass
    same = run("print", a, "--port", ctl.port, "--baud", 1000000, "--log", tmp_path / "other.jsonl")
    assert same.returncode == 18 and "another heoslice process" in one_line(same.stderr)
    assert proc.poll() is None, "the first print ended before the checks ran"
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    assert ctl.executed(job_of(tmp_path / "a.print-log.jsonl")) == list(range(40))
    assert ctl.executed(job_of(tmp_path / "b.print-log.jsonl")) == []
    killed = start_print(b, ctl.port)
    wait_layers(tmp_path / "b.print-log.jsonl", 1)
    killed.kill()
    killed.communicate(timeout=10)
    with hold_stack(b, "slicing into it"):
        pass


def test_stack_changed_under_a_print(tmp_path, controller):
    """A layer file rewritten during the print stops it with exit 19, one line saying the stack changed, ABORT sent."""
    ctl = controller("--set", "rx_buffer=400", layer_time=0.05)
    stack = make_stack(tmp_path / "s", disc_masks(30))
    proc = start_print(stack, ctl.port)
    wait_layers(tmp_path / "s.print-log.jsonl", 2)
    (stack / "layer_00025.tif").write_bytes(b"not the layer")
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 19 and "changed while it was being printed" in one_line(err)
    assert one_line(err).count("layer 25:") == 1, "the layer named once"
    ctl.wait_for("abort")
    assert 25 not in ctl.executed()


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.mark.slow  # among the slowest (README "Development"): waits on a paced simulator
def test_a_restarted_simulator_is_detected_as_a_reset(tmp_path, controller):
    """A controller killed and started again at the same address has a fresh boot id (same --seed): the print
    reports a reset (exit 14) naming --from-layer, instead of resuming."""
    address = f"127.0.0.1:{free_port()}"
    first = controller("--seed", "0", listen=address, layer_time=0.05)
    stack = make_stack(tmp_path / "s", disc_masks(30))
    proc = start_print(stack, first.port)
    wait_layers(tmp_path / "s.print-log.jsonl", 3)
    boot = first.boot_id()
    first.proc.kill()
    second = controller("--seed", "0", listen=address, layer_time=0.05)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 14 and "reset" in one_line(err) and "--from-layer" in err
    assert second.boot_id() != boot


@pytest.mark.slow  # among the slowest (README "Development"): waits on a paced simulator
def test_misbehaving_controllers_end_in_bounded_time(tmp_path, controller):
    """Controllers granting no credit, offering window 0, claiming absurd progress, never acknowledging data, or
    no longer reading end the print within seconds with their documented exit codes and one line."""
    stack = make_stack(tmp_path / "s", disc_masks(10))
    cases = [("sim://?rx_buffer=0", 12, 2.0), ("sim://?window=0", 12, 2.0),
             ("sim://?claim_completed=2147483647", 12, 2.0), ("sim://?lose_data_from_layer=0", 13, 7.0)]
    for port, code, bound in cases:
        start = time.monotonic()
        result = run("print", stack, "--port", port, "--log", tmp_path / "log.jsonl")
        assert result.returncode == code and one_line(result.stderr), (port, result.stderr)
        assert time.monotonic() - start < bound + 2.0, port
    assert (tmp_path / "log.jsonl").stat().st_size < 20_000
    deaf = controller("--set", "stop_reading_at_layer=2")
    log = tmp_path / "deaf.jsonl"
    result = run("print", stack, "--port", deaf.port, "--baud", 1000000, "--log", log)
    assert result.returncode == 11 and one_line(result.stderr)
    assert dead_link_reported_within(log) < 5.0


def dead_link_reported_within(log: Path) -> float:
    """Seconds from the last layer the controller confirmed to the logged error: the documented dead-link bound,
    on the host's clock (heoslice's start-up, seconds on a loaded machine, comes before and is not in it)."""
    import datetime

    records = [r for r in events(log)[1:] if r["event"] in ("connected", "layer", "error")]
    alive, error = records[-2], records[-1]
    assert error["event"] == "error" and alive["event"] != "error", records
    seconds = [datetime.datetime.fromisoformat(r["time"]).timestamp() for r in (alive, error)]
    return seconds[1] - seconds[0]


@pytest.mark.parametrize("fault, seed, features", [("byte_error_rate", 1, 1), ("byte_error_rate", 2, 1),
                                                   ("byte_drop_rate", 3, 1), ("byte_error_rate", 4, 0)])
def test_a_1e_2_link_completes(tmp_path, controller, fault, seed, features):
    """At 1e-2 byte errors or drops (incompressible layers, pty), with selective acknowledgement and without it
    (features=0: plain go-back-N), the print completes, each layer exactly once."""
    ctl = controller("--set", f"{fault}=1e-2", "--set", f"features={features}", "--seed", str(seed))
    noise = [np.random.default_rng([seed, k]).random((32, 96)) < 0.5 for k in range(8)]
    stack = make_stack(tmp_path / "s", noise)
    result = run("print", stack, "--port", ctl.port, "--baud", 1000000)
    assert result.returncode == 0, result.stderr
    log = tmp_path / "s.print-log.jsonl"
    assert ctl.executed(job_of(log)) == list(range(8))
    assert [r["sack"] for r in events(log) if r["event"] == "connected"] == [bool(features)]


@pytest.mark.slow  # among the slowest (README "Development"): waits on a paced simulator
def test_simulator_options_checked_logging_and_fresh_boot_ids(tmp_path, controller):
    """Bad simulator options are one line (sim:// exit 10, --set exit 2); two starts with one seed draw different
    boot ids; the controller logs connections, jobs and layers on stderr, and nothing with -q; sim:// is fast."""
    stack = make_stack(tmp_path / "s", disc_masks(40))
    bad = run("print", stack, "--port", "sim://?baud=0")
    assert bad.returncode == 10 and "baud must be > 0" in one_line(bad.stderr)
    bad_set = run("controller", "--pty", "--set", "byte_error_rate=2")
    assert bad_set.returncode == 2 and "byte_error_rate" in one_line(bad_set.stderr)
    start = time.monotonic()
    assert run("print", stack, "--port", "sim://").returncode == 0
    assert time.monotonic() - start < 10
    one, two = controller(), controller("-q")
    assert run("print", stack, "--port", one.port, "--baud", 1000000).returncode == 0
    assert one.boot_id() != controller("--duration", "0.3").boot_id()
    for text in ("connection: session", ": begun at layer 0 of 40", "layer 39 executed", "done: 40 layers"):
        one.wait_for(text)
    assert run("print", stack, "--port", two.port, "--baud", 1000000).returncode == 0
    two.stop()
    assert two.lines == []


def test_a_job_finished_after_its_host_was_killed_is_not_printed_again(tmp_path, controller):
    """A job smaller than the controller's receive buffer is all sent before the head is done; kill -9 the host,
    the controller finishes alone. Then the same command, and --from-layer N (the killed run's log count), are
    each refused with one line (exit 20) naming the job, the layers the head executed and --restart; the head
    executed every layer exactly once. --restart prints it again, on purpose."""
    ctl = controller(layer_time=0.1)
    stack = make_stack(tmp_path / "s", disc_masks(20))
    log = tmp_path / "s.print-log.jsonl"
    proc = start_print(stack, ctl.port)
    ctl.wait_for("end received")
    proc.kill()
    proc.communicate(timeout=10)
    job = job_of(log)
    logged = sum(r["event"] == "layer" for r in events(log))
    assert logged < 20
    ctl.wait_for(f"job {job} done", timeout=20)
    time.sleep(3.2)  # the killed host's claim lapses
    for extra in ((), ("--from-layer", logged)):
        again = run("print", stack, "--port", ctl.port, "--baud", 1000000, *extra)
        line = one_line(again.stderr)
        assert again.returncode == 20 and job in line and "up to 19, all 20" in line and "--restart" in line
    assert ctl.executed(job) == list(range(20))
    restarted = run("print", stack, "--port", ctl.port, "--baud", 1000000, "--restart")
    assert restarted.returncode == 0, restarted.stderr
    assert ctl.executed(job) == list(range(20)) * 2


@pytest.mark.parametrize("listen", ["127.0.0.1:99999", "127.0.0.1:-1", "127.0.0.1:abc", "127.0.0.1"])
def test_a_bad_listen_address_is_one_line(run_cli, listen):
    """`controller --listen` with a port that is not 0..65535 (or none): one line naming it and the form, exit 2,
    not an internal error."""
    code, out, err = run_cli("controller", "--listen", listen, "-q")
    assert code == 2 and err.count("\n") == 1 and f"--listen {listen}: expected HOST:PORT" in err, err
