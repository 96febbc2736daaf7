"""Distribution functions (eq. 2-5): defaults, the equations, refusals.

References: the equations written out in numpy.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from heoslice.errors import InputError
from heoslice.material import (
    FUNCTION_KINDS,
    DistributionFunction,
    evaluate,
    make_function,
)

R = np.linspace(0.0, 1.0, 1001)
coefficient = st.floats(-10, 10, allow_nan=False)


# --- functions ----------------------------------------------------------------------------

def test_defaults_span_zero_to_one():
    """With make_function's defaults, linear, quadratic and sine reach exactly 0 and 1 over r in [0, 1]."""
    for kind in ("linear", "quadratic", "sine"):
        f = evaluate(make_function(kind), R)
        assert f.min() == pytest.approx(0.0, abs=1e-12) and f.max() == pytest.approx(1.0, abs=1e-12), kind


def test_default_shapes():
    """Defaults: linear f = r, quadratic f = r^2, sine f = 0.5 + 0.5 sin(2 pi r), constant f = 1."""
    assert np.array_equal(evaluate(make_function("linear"), R), R)
    assert np.allclose(evaluate(make_function("quadratic"), R), R ** 2, rtol=0, atol=1e-15)
    assert np.allclose(evaluate(make_function("sine"), R), 0.5 + 0.5 * np.sin(2 * np.pi * R), rtol=0, atol=1e-15)
    assert np.array_equal(evaluate(make_function("constant"), R), np.ones_like(R))


@given(alpha=coefficient, beta=coefficient, lam=coefficient)
def test_equations_2_to_5(alpha, beta, lam):
    """evaluate() is eq. 2 (lam), 3 (alpha r + lam), 4 (alpha r^2 + beta r + lam), 5 (alpha sin(beta r) + lam)."""
    r = np.linspace(0, 1, 33)
    expected = {
        "constant": np.full_like(r, lam),
        "linear": alpha * r + lam,
        "quadratic": alpha * r ** 2 + beta * r + lam,
        "sine": alpha * np.sin(beta * r) + lam,
    }
    for kind, values in expected.items():
        func = make_function(kind, alpha=None if kind == "constant" else alpha,
                             beta=None if kind in ("constant", "linear") else beta, lam=lam)
        assert np.allclose(evaluate(func, r), values, rtol=1e-12, atol=1e-12), kind
        assert np.allclose(func(r), values, rtol=1e-12, atol=1e-12)


def test_sine_periods():
    """periods = p sets beta = 2 pi p: f completes p periods over r in [0, 1]; beta and periods conflict."""
    func = make_function("sine", periods=3)
    assert func.beta == pytest.approx(6 * math.pi)
    assert evaluate(func, np.array([1 / 12, 3 / 12]))[0] == pytest.approx(1.0)
    with pytest.raises(InputError, match="beta or periods"):
        make_function("sine", beta=2.0, periods=1.0)


@pytest.mark.parametrize("kind", ["spline", "", "Linear2"])
def test_unknown_kind(kind):
    """An unknown function kind is an InputError listing the known ones."""
    with pytest.raises(InputError, match="unknown distribution function"):
        make_function(kind)


def test_kind_is_case_insensitive_and_bad_numbers_refused():
    """'LINEAR' is linear; NaN or infinite coefficients, and coefficients the kind does not use, are refused."""
    assert make_function("LINEAR").kind == "linear"
    with pytest.raises(InputError, match="alpha: must be finite"):
        make_function("linear", alpha=float("nan"))
    with pytest.raises(InputError, match="only used with the 'expression'"):
        make_function("linear", expression="r")
    with pytest.raises(InputError, match="periods: only applies"):
        make_function("linear", periods=2)
    with pytest.raises(InputError, match="beta is not used by the linear"):
        make_function("linear", beta=2)
    with pytest.raises(InputError, match="alpha and beta are not used by the constant"):
        make_function("constant", alpha=1, beta=2)


def test_function_is_frozen_dataclass():
    """DistributionFunction is immutable and comparable (a specification, not state)."""
    func = make_function("linear")
    assert func == DistributionFunction("linear", 1.0, 0.0, 0.0)
    with pytest.raises(AttributeError):
        func.alpha = 2.0  # type: ignore[misc]
    assert set(FUNCTION_KINDS) == {"constant", "linear", "quadratic", "sine", "expression"}


@pytest.mark.parametrize("kind, options, culprit", [
    ("sine", dict(periods=1e308), "periods"),
    ("quadratic", dict(alpha=1e308, beta=1e308), "alpha"),
    ("linear", dict(alpha=1e308, lam=1e308), "alpha"),
    ("expression", dict(expression="1/r"), "expression"),
    ("expression", dict(expression="exp(1000*r)"), "expression"),
])
def test_non_finite_fractions_are_refused_naming_the_parameter(kind, options, culprit):
    """A function whose value is infinite or NaN somewhere on r in [0, 1] is refused (InputError naming the
    parameter that caused it), never handed on to be clipped into M1 or M2, and without numpy warnings."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InputError, match=rf"^{culprit}: "):
            make_function(kind, **options)(np.linspace(0.0, 1.0, 101))


def test_cli_refuses_non_finite_fractions_naming_the_option(run_cli, tmp_path):
    """`color --func sine --periods 1e308`: exit 2, one line naming --periods, nothing written, no warning."""
    from heoslice import procedural

    model = tmp_path / "box.ply"
    procedural.box().export(model)
    code, out, err = run_cli("color", model, "--func", "sine", "--periods", "1e308")
    assert code == 2 and err.count("\n") == 1 and err.startswith("heoslice: error: --periods: "), err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["box.ply"]
    code, out, err = run_cli("color", model, "--func", "quadratic", "--alpha", "1e308", "--beta", "1e308")
    assert code == 2 and err.startswith("heoslice: error: --alpha: ") and "Warning" not in err, err
