"""Safe expressions in r: values against numpy formulas, refusals of everything outside the whitelist."""

from __future__ import annotations

import numpy as np
import pytest

from heoslice.errors import InputError
from heoslice.material import compile_expression, evaluate, make_function

R = np.linspace(0.0, 1.0, 1001)


# --- expressions --------------------------------------------------------------------------

@pytest.mark.parametrize("text, reference", [
    ("r", lambda r: r),
    ("0.5 - 0.5*cos(2*pi*r)", lambda r: 0.5 - 0.5 * np.cos(2 * np.pi * r)),
    ("r**2*(3-2*r)", lambda r: r ** 2 * (3 - 2 * r)),
    ("-r + 1", lambda r: 1 - r),
    ("clip(2*r - 0.5, 0, 1)", lambda r: np.clip(2 * r - 0.5, 0, 1)),
    ("max(r, 0.3) + min(r, 0.1)", lambda r: np.maximum(r, 0.3) + np.minimum(r, 0.1)),
    ("exp(-r/0.2) * sqrt(abs(r - 0.5))", lambda r: np.exp(-r / 0.2) * np.sqrt(np.abs(r - 0.5))),
    ("floor(4*r)/4", lambda r: np.floor(4 * r) / 4),
    ("0.25", lambda r: np.full_like(r, 0.25)),
    ("e**-r", lambda r: np.e ** -r),
])
def test_expression_values(text, reference):
    """A whitelisted expression evaluates to the same values as the numpy formula, vectorised over r."""
    func = make_function("expression", expression=text)
    assert np.allclose(evaluate(func, R), reference(R), rtol=1e-14, atol=1e-14)
    assert evaluate(func, R).shape == R.shape


@pytest.mark.parametrize("text, fragment", [
    ("__import__('os').system('true')", "unknown function"),
    ("r.__class__", "attribute is not allowed"),
    ("().__class__.__bases__", "not allowed"),
    ("open('x')", "unknown function"),
    ("x + 1", "unknown name"),
    ("lambda: 1", "lambda is not allowed"),
    ("[r for r in 'ab']", "not allowed"),
    ("'text'", "only numbers"),
    ("True + r", "only numbers"),
    ("1j * r", "only numbers"),
    ("r if r else 0", "not allowed"),
    ("r > 0.5", "not allowed"),
    ("r % 2", "not allowed"),
    ("r^2", r"use \*\* \(r\*\*2"),
    ("1 - (r ^ 3)", r"\^ is not a power here, use \*\*"),
    ("sin(r, 2)", "takes 1 argument"),
    ("clip(r, a_min=0, a_max=1)", "takes 3 argument"),
    ("np.sin(r)", "unknown function"),
    ("sin", "is a function"),
    ("r +", "does not parse"),
    ("", "needs an expression"),
    ("r" + "+r" * 300, "too complex"),
    ("x" * 2000, "longer than"),
])
def test_expression_refusals(text, fragment):
    """Anything outside numbers, r, pi, e, + - * / **, unary +/- and whitelisted calls is an InputError."""
    with pytest.raises(InputError, match=fragment):
        evaluate(make_function("expression", expression=text), R)


def test_expression_deep_nesting_and_nan():
    """Deep nesting is an InputError or a value, never a crash; NaN results name the r where they occur."""
    try:
        compile_expression("(" * 300 + "r" + ")" * 300)
    except InputError:
        pass
    with pytest.raises(InputError, match=r"undefined \(NaN\) at r = "):
        evaluate(make_function("expression", expression="sqrt(r - 0.5)"), R)
    huge = evaluate(make_function("expression", expression="9**9**9 * r"), np.array([0.5]))
    assert np.isinf(huge).all()  # floats overflow to inf; the blend clips them, nothing hangs
