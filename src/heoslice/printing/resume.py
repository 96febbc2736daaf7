"""Where a print run starts, decided from the controller's HELLO_ACK (docs/protocol.md section 2) and the print
log's last run of the job.

A pure function of what the controller reports, what the log recorded (:class:`heoslice.printing.log.LoggedRun`:
a controller restarted since remembers nothing) and what the user typed (``--resume``, ``--restart``,
``--from-layer``), so no layer the controller holds as queued, executing or done for this job is sent again, none
is skipped, and an unfinished job is never continued or overwritten without being asked.
"""

from __future__ import annotations

from dataclasses import dataclass

from heoslice.errors import ControllerResetError, FinishedJobError, InputError, UnfinishedJobError
from heoslice.printing import protocol as P
from heoslice.printing.job import JobSpec
from heoslice.printing.log import LoggedRun
from heoslice.printing.stream import check_from_layer


@dataclass(frozen=True)
class Start:
    """The decision: first layer to send; ABORT the controller's job first; RESUME a paused one; the log event."""

    layer: int
    abort_first: bool = False
    resume_paused: bool = False
    event: str | None = None  # "resume" or "restart", logged with the controller's job


def unfinished(ack: P.HelloAck) -> bool:
    """True when the controller holds a job that was neither completed nor left with nothing printed or queued."""
    if ack.job_id == 0:
        return False
    if ack.state in (P.STATE_RECEIVING, P.STATE_PAUSED):
        return True
    if ack.state in (P.STATE_ABORTED, P.STATE_IDLE):
        return 0 <= ack.last_completed < ack.layer_count - 1
    return False


def finished(ack: P.HelloAck, job: JobSpec) -> bool:
    """True when the controller reports ``job`` itself as printed to its last layer (done, or idle or aborted
    after its last layer): a run killed after sending the whole job, whose controller finished it alone."""
    return (ack.job_id == job.job_id and ack.layer_count == job.layer_count
            and ack.last_completed >= job.layer_count - 1
            and ack.state in (P.STATE_DONE, P.STATE_IDLE, P.STATE_ABORTED))


def decide_start(ack: P.HelloAck, job: JobSpec, port: str, label: str, *, from_layer: int | None = None,
                 resume: bool = False, restart: bool = False, logged: LoggedRun | None = None) -> Start:
    """The :class:`Start` of a new run, or the one-line refusal (UnfinishedJobError exit 17, reset exit 14).

    ``label`` names this run's stack in messages; ``logged`` is the print log's last run of this job: one that
    printed some layers and did not finish, on a controller that holds no unfinished job (restarted or power-cycled
    since, its memory of the job gone), is continued only from the layer after it (--from-layer), or restarted.
    """
    if resume and restart:
        raise InputError("--resume and --restart exclude each other")
    if restart and from_layer is not None:
        raise InputError("--restart starts at layer 0; it excludes --from-layer")
    if from_layer is not None:
        check_from_layer(job, from_layer)
    state = P.STATE_NAMES.get(ack.state, str(ack.state))
    if finished(ack, job):
        if restart:
            return Start(0, event="restart")
        asked = f" (--from-layer {from_layer} included)" if from_layer is not None else ""
        raise FinishedJobError(
            f"{port}: the controller reports job {ack.job_id:08x} ({label}) finished: the head executed its layers "
            f"up to {ack.last_completed}, all {ack.layer_count}; nothing was sent{asked}; rerun with --restart "
            "to print it again on purpose")
    if not unfinished(ack) and ack.job_id != job.job_id and not restart and logged is not None \
            and not logged.finished and 0 <= logged.last_completed < job.layer_count - 1:
        following = logged.last_completed + 1
        if from_layer != following:
            raise ControllerResetError(
                f"{port}: the print log shows {label} printed up to layer {logged.last_completed} by a run that did "
                f"not finish, and the controller holds no unfinished print of it (restarted or power-cycled since?): "
                f"check the part, then rerun with --from-layer {following} (or --restart to start over)",
                next_layer=following)
        return Start(from_layer, event="resume")
    if not unfinished(ack):
        if resume:
            raise InputError(f"--resume: {port} holds no unfinished job to resume (controller {state}, "
                             f"job {ack.job_id:08x}); rerun without --resume to print from layer 0")
        return Start(from_layer or 0)
    mine = ack.job_id == job.job_id
    theirs = ack.job_name.decode("utf-8", "replace")
    stack = label if mine else f"another stack, {theirs!r}" if theirs else "another stack"
    held = f"job {ack.job_id:08x} ({stack}), {state}, last completed layer {ack.last_completed}"
    if restart:
        return Start(0, abort_first=ack.state != P.STATE_IDLE, event="restart")
    if not mine:
        raise UnfinishedJobError(f"{port}: the controller holds an unfinished {held}; rerun with --restart to "
                                 f"abort it and print {label} from layer 0")
    after_reset = ack.state == P.STATE_IDLE
    done = ack.last_completed
    if after_reset:
        if from_layer is None:
            raise ControllerResetError(
                f"{port}: the controller was reset during an earlier print of {held}; check the part, then rerun "
                f"with --from-layer {done + 1} (or --restart to start over)", next_layer=done + 1)
        if from_layer <= done:
            raise UnfinishedJobError(f"--from-layer {from_layer}: layers up to {done} of {label} were already "
                                     f"printed; use --from-layer {done + 1}, or --restart to start over")
        if from_layer > done + 1:
            raise UnfinishedJobError(f"--from-layer {from_layer}: layers {done + 1} to {from_layer - 1} of {label} "
                                     f"were not printed (the controller completed layer {done}); use --from-layer "
                                     f"{done + 1}, or --restart to start over")
        return Start(from_layer, event="resume")
    resume_at = ack.last_queued + 1
    if from_layer is not None and from_layer != resume_at:
        raise UnfinishedJobError(f"--from-layer {from_layer}: the controller holds layers up to {ack.last_queued} "
                                 f"of {held}; --resume continues at layer {resume_at}, --restart starts over")
    if not resume and from_layer is None:
        raise UnfinishedJobError(f"{port}: the controller holds an unfinished print of {held}; rerun with --resume "
                                 f"to continue at layer {resume_at}, or --restart to abort it and start at layer 0")
    return Start(resume_at, resume_paused=ack.state == P.STATE_PAUSED, event="resume")
