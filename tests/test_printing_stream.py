"""Tests of printing/stream.py's sizing of a transfer (plan_transfer): exact, it counts the frames and wire bytes
of the print's own message stream; sampled, it is within the bound the help text states of the exact figures."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers import in_process
from hypothesis import given, settings
from hypothesis import strategies as st
from printing_jobs import synthetic_job

from heoslice import procedural
from heoslice.errors import InputError, VerifyError
from heoslice.printing import (SAMPLE_LAYERS, JobSpec, dry_run, encoded_layers, job_messages, plan_transfer,
                               stack_job)
from heoslice.printing import protocol as P
from heoslice.printing.stream import regression_total, sample_layers

#: The estimate's bound the --dry-run help states (relative to --exact).
ESTIMATE_BOUND = 0.01


@given(st.integers(0, 1000), st.integers(1, 3000), st.integers(1, 100))
def test_sample_layers_takes_one_layer_of_each_equal_run(first, total, count):
    """The sample holds min(count, total) distinct layers of first..first+total-1 in order, the k-th (as the span
    [layer, layer + 1)) meeting the k-th of ``count`` equal runs of the stack's height (so it spreads over the
    whole stack), and is the same when asked again."""
    chosen = sample_layers(first, first + total, count)
    assert chosen == sample_layers(first, first + total, count)
    if total <= count:
        assert chosen == list(range(first, first + total))
        return
    assert len(chosen) == count and chosen == sorted(set(chosen))
    for run, layer in enumerate(chosen):
        assert (layer - first) * count < (run + 1) * total and (layer - first + 1) * count > run * total


@settings(max_examples=50)
@given(st.integers(2, 500), st.integers(0, 2**32 - 1), st.floats(-50, 50), st.floats(0, 100))
def test_regression_total_is_exact_for_a_figure_linear_in_the_auxiliary(layers, seed, intercept, slope):
    """y = a + b x on every layer: the estimate from any sample of two or more distinct x is the true sum; with x
    the same on every sampled layer it is N times the sample's mean."""
    rng = np.random.default_rng(seed)
    x = rng.integers(0, 10**6, layers).astype(float)
    y = intercept + slope * x
    chosen = rng.choice(layers, size=min(layers, 8), replace=False)
    if np.ptp(x[chosen]) > 0:
        assert regression_total(y[chosen], x[chosen], x) == pytest.approx(y.sum(), rel=1e-9, abs=1e-6)
    flat = np.full(layers, 7.0)
    assert regression_total(y[chosen], flat[chosen], flat) == pytest.approx(layers * y[chosen].mean())


def stream_figures(job, get_layer, from_layer: int, max_payload: int) -> tuple[int, int]:
    """(frames, wire bytes) of the layers' messages in the print's stream (job_messages), JOB_BEGIN/END aside."""
    messages = [message for message, layer, _ in job_messages(job, get_layer, from_layer, lambda: max_payload,
                                                              P.ALL_ENCODINGS)
                if not isinstance(message, (P.JobBegin, P.JobEnd))]
    return len(messages), sum(P.wire_size(len(P.pack_message(message)[1])) for message in messages)


@pytest.mark.parametrize("from_layer, max_payload", [(0, 1024), (3, 200)])
def test_exact_plan_counts_the_frames_a_print_sends(from_layer, max_payload):
    """Without a sample every layer is encoded: frames and wire bytes are those of the print's message stream at
    that payload, the raw bytes every channel's, and the result says it is not estimated."""
    job, get_layer = synthetic_job(9, width=300, height=40, channels=2)
    plan = plan_transfer(job, get_layer, max_payload=max_payload, from_layer=from_layer, workers=1)
    assert (plan["frames"], plan["wire_bytes"]) == stream_figures(job, get_layer, from_layer, max_payload)
    assert plan["raw_bytes"] == (9 - from_layer) * 2 * job.channel_bytes
    assert plan["estimated"] is False and plan["layers_encoded"] == plan["layers"] == 9 - from_layer


def test_a_sample_as_large_as_the_stack_is_exact():
    """A stack of no more layers than the sample is encoded whole: the same figures as without a sample."""
    job, get_layer = synthetic_job(SAMPLE_LAYERS, width=200, height=20)
    assert plan_transfer(job, get_layer, sample=SAMPLE_LAYERS, workers=1) == plan_transfer(job, get_layer, workers=1)


@pytest.fixture(scope="module")
def ball_stack(tmp_path_factory) -> Path:
    """A graded ball of 8 mm radius with droplet masks, 160 layers of 284 x 284 px: layers of every size."""
    folder = tmp_path_factory.mktemp("ball")
    model = folder / "ball.ply"
    model.write_bytes(procedural.sphere(8.0, 3).export(file_type="ply", encoding="binary"))
    assert in_process("slice", model, "--layer", "0.1", "--dpi", "400", "--grade", "linear", "--to", "0,255,0",
                      "--nozzle", "0.2", "--channels", "-o", folder / "stack") == 0
    return folder / "stack"


def test_stored_bytes_are_each_layers_files(ball_stack):
    """The job carries the bytes each layer's files (its own and its masks') take in the stack."""
    job, _ = stack_job(ball_stack)
    manifest = json.loads((ball_stack / "manifest.json").read_text())
    assert job.stored_bytes == tuple(
        sum((ball_stack / name).stat().st_size for name in [entry["file"], *(c["file"] for c in entry["channels"])])
        for entry in manifest["layers"])


@pytest.mark.parametrize("from_layer", [0, 17])
def test_sampled_plan_is_within_its_bound_of_the_exact_one(ball_stack, from_layer):
    """From SAMPLE_LAYERS of the ball's 160 layers (or of those from layer 17) the frames and wire bytes are
    within ESTIMATE_BOUND of encoding every layer, the raw bytes exact, and the result says it is estimated."""
    job, get_layer = stack_job(ball_stack)
    exact = plan_transfer(job, get_layer, from_layer=from_layer)
    estimate = plan_transfer(job, get_layer, from_layer=from_layer, sample=SAMPLE_LAYERS)
    assert estimate["estimated"] is True and estimate["layers_encoded"] == SAMPLE_LAYERS
    assert estimate["raw_bytes"] == exact["raw_bytes"] and estimate["layers"] == exact["layers"]
    for key in ("frames", "wire_bytes"):
        assert abs(estimate[key] / exact[key] - 1) <= ESTIMATE_BOUND, (key, estimate[key], exact[key])


def test_dry_run_says_its_figures_are_estimated_and_exact_encodes_every_layer(ball_stack, run_cli):
    """`print --dry-run` says it estimated from 32 of 160 layers (text and JSON); with --exact the JSON gives the
    exact plan's figures; --exact without --dry-run is a usage error (exit 2, one line); the help states the
    sample and the bound the tests hold the estimate to."""
    code, out, err = run_cli("print", ball_stack, "--dry-run")
    assert code == 0 and f"(estimated from {SAMPLE_LAYERS} of 160 layers; --exact encodes every layer)" in out
    code, out, _ = run_cli("print", ball_stack, "--dry-run", "--json")
    summary = json.loads(out)
    assert code == 0 and summary["estimated"] is True and summary["layers_encoded"] == SAMPLE_LAYERS
    code, out, _ = run_cli("print", ball_stack, "--dry-run", "--exact", "--json")
    job, get_layer = stack_job(ball_stack)
    exact = plan_transfer(job, get_layer)
    summary = json.loads(out)
    assert code == 0 and summary["estimated"] is False and summary["layers_encoded"] == 160
    assert {key: summary[key] for key in exact} == exact
    code, out, err = run_cli("print", ball_stack, "--exact")
    assert code == 2 and "--exact" in err and err.count("\n") == 1 and out == ""
    code, out, _ = run_cli("print", "--help")
    assert code == 0 and f"{SAMPLE_LAYERS} layers" in " ".join(out.split())
    assert f"within {100 * ESTIMATE_BOUND:g} % of --exact" in " ".join(out.split())


def test_blank_layers_the_sample_misses_are_counted_exactly(tmp_path):
    """Two 20 mm boxes 0.3 mm apart, at 0.025 mm layers: 12 blank layers among 400, fewer than the sample's
    stride, so no sampled layer is blank. The blank layers encode alike and are counted from one of them, so
    the estimate stays within ESTIMATE_BOUND of the exact plan (it was 1.2 % over in frames and 2.3 % in wire
    bytes when they were left to the regression on the other layers' sizes)."""
    import trimesh

    boxes = [trimesh.creation.box((20.0, 20.0, 4.85)) for _ in range(2)]
    boxes[1].apply_translation((0.0, 0.0, 4.85 + 0.3))
    model = tmp_path / "boxes.ply"
    model.write_bytes(trimesh.util.concatenate(boxes).export(file_type="ply", encoding="binary"))
    assert in_process("slice", model, "--layer", "0.025", "--dpi", "200", "--grade", "linear", "--to", "0,255,0",
                      "--halftone", "blue-noise", "-o", tmp_path / "stack") == 0
    job, get_layer = stack_job(tmp_path / "stack")
    assert job.layer_count == 400 and 10 <= sum(job.blank) <= 14
    exact = plan_transfer(job, get_layer)
    estimate = plan_transfer(job, get_layer, sample=SAMPLE_LAYERS)
    assert estimate["estimated"] is True and estimate["layers_encoded"] == SAMPLE_LAYERS + 1
    for key in ("frames", "wire_bytes"):
        assert abs(estimate[key] / exact[key] - 1) <= ESTIMATE_BOUND, (key, estimate[key], exact[key])
    with pytest.raises(ValueError, match="at least one layer"):
        plan_transfer(job, get_layer, sample=0)


def test_few_layers_with_solid_pixels_and_many_blank_ones_are_sized_exactly_from_one_blank_layer():
    """A job of 5 layers with solid pixels among 200 blank ones (nothing to sample): the blank layers are counted
    from one of them and the others encoded, 6 layers in all, with the exact plan's figures."""
    from dataclasses import replace

    job, get_layer = synthetic_job(205, width=120, height=30, channels=2)
    filled = {0, 50, 100, 150, 204}

    def layer(index: int) -> list[bytes]:
        return get_layer(index) if index in filled else [bytes(job.channel_bytes)] * job.channels

    job = replace(job, blank=tuple(index not in filled for index in range(205)))
    estimate = plan_transfer(job, layer, sample=SAMPLE_LAYERS, workers=1)
    assert estimate["layers_encoded"] == 6 and estimate["estimated"] is False
    assert {key: estimate[key] for key in ("frames", "wire_bytes", "raw_bytes")} == {
        key: value for key, value in plan_transfer(job, layer, workers=1).items()
        if key in ("frames", "wire_bytes", "raw_bytes")}


def test_channels_equal_to_an_earlier_one_are_framed_as_the_print_sends_them():
    """A layer whose droplet mask repeats its solid mask (a part of one material) and a third channel of the same
    length but other bytes: the exact plan is the print's stream, each channel framed from its own bytes."""
    job, get_layer = synthetic_job(6, width=300, height=40, channels=2)
    job = JobSpec(job.job_id, job.layer_count, 3, job.width, job.height)

    def layer(index: int) -> list[bytes]:
        solid, other = get_layer(index)
        return [solid, solid, other]

    plan = plan_transfer(job, layer, max_payload=200, workers=1)
    assert (plan["frames"], plan["wire_bytes"]) == stream_figures(job, layer, 0, 200)


@pytest.mark.parametrize("from_layer, sample", [(0, SAMPLE_LAYERS), (17, SAMPLE_LAYERS), (0, None), (5, 3)])
def test_dry_run_sizes_from_the_verification_as_the_job_and_its_plan_do(ball_stack, from_layer, sample):
    """dry_run gives stack_job's job and plan_transfer's figures (sampled or exact, from any layer), every layer
    it encodes encoded from the verification's reading of it: nothing is left to size (and read) after it."""
    sized = []
    job, plan = dry_run(ball_stack, from_layer=from_layer, sample=sample, sizing=lambda done, total: sized.append(1))
    expected_job, get_layer = stack_job(ball_stack)
    assert job == expected_job and job.stored_bytes == expected_job.stored_bytes
    assert plan == plan_transfer(job, get_layer, from_layer=from_layer, sample=sample)
    assert sized == []


def test_dry_run_refuses_what_a_print_refuses(ball_stack, tmp_path):
    """A layer whose file changed (one of the sampled layers) is the verification's refusal, word for word as
    stack_job's; a --from-layer outside the stack is plan_transfer's after a clean verification."""
    broken = tmp_path / "broken"
    shutil.copytree(ball_stack, broken)
    manifest = json.loads((broken / "manifest.json").read_text())
    job, _ = stack_job(ball_stack)
    sampled = encoded_layers(job, 0, SAMPLE_LAYERS)[3]
    path = broken / manifest["layers"][sampled]["file"]
    data = bytearray(path.read_bytes())
    data[-1] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(VerifyError) as printing:
        stack_job(broken)
    with pytest.raises(VerifyError) as dry:
        dry_run(broken)
    assert str(dry.value) == str(printing.value) and "sha256" in str(dry.value)
    with pytest.raises(InputError, match="--from-layer 160 is outside the stack's layers 0..159"):
        dry_run(ball_stack, from_layer=160)
