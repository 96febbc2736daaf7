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
    """Deep nesting is an InputError or a value, never a crash; NaN and infinite results name the r where they
    occur."""
    try:
        compile_expression("(" * 300 + "r" + ")" * 300)
    except InputError:
        pass
    with pytest.raises(InputError, match=r"undefined \(NaN\) at r = "):
        evaluate(make_function("expression", expression="sqrt(r - 0.5)"), R)
    with pytest.raises(InputError, match=r"gives f = inf at r = 0.5"):  # overflow is refused, nothing hangs
        evaluate(make_function("expression", expression="9**9**9 * r"), np.array([0.5]))


@pytest.mark.parametrize("text", ["ｒ", "𝑟*2", "sin(ｒ)", "ᵣ", "r²", "r—1", "١"])
def test_non_ascii_expressions_are_refused(run_cli, tmp_path, text):
    """An expression with a non-ASCII character (which Python would fold to ASCII, or the ASCII PLY header could
    not hold) is one line naming --expr and the character, exit 2, nothing written."""
    from heoslice import procedural

    model = tmp_path / "box.ply"
    procedural.box().export(model)
    code, _, err = run_cli("color", model, "--expr", text)
    assert code == 2 and err.count("\n") == 1 and err.startswith("heoslice: error: --expr: ") and "U+" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["box.ply"]
