"""Material distribution functions f(r) (paper section II.B, eq. 2-5): one table of kinds.

f(r) is the fraction of the second material M2 at the normalised distance r in [0, 1]
(eq. 1 in :mod:`heoslice.material.materials` turns f into a blend). Every kind is one
row of :data:`FUNCTIONS`: its equation, the coefficients it uses with their defaults
(chosen so that f spans 0..1 over r in [0, 1]), its formula and how it is written:

=========== ========================= =======================================
kind        f(r)                      defaults
=========== ========================= =======================================
constant    lam                 (2)   lam = 1 (the whole model is M2)
linear      alpha r + lam       (3)   alpha = 1, lam = 0
quadratic   alpha r^2 + beta r + lam  alpha = 1, beta = 0, lam = 0      (4)
sine        alpha sin(beta r) + lam   alpha = 0.5, lam = 0.5,
                                (5)   beta = 2 pi periods, periods = 1
expression  a formula in r            e.g. ``"0.5 - 0.5*cos(3*pi*r)"``
=========== ========================= =======================================

Errors name the parameter of :func:`make_function` (``kind``, ``alpha``, ``beta``,
``lam``, ``periods``, ``expression``), for the CLI to map to its options.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from heoslice.errors import InputError, shown
from heoslice.material.expressions import compile_expression, evaluate_expression


@dataclass(frozen=True)
class DistributionFunction:
    """f(r) of eq. 2-5 (or a user ``expression`` in r); f is the fraction of M2 at r."""

    kind: str
    alpha: float = 1.0
    beta: float = 0.0
    lam: float = 0.0
    expression: str | None = None

    def __call__(self, r: np.ndarray) -> np.ndarray:
        return evaluate(self, r)

    def describe(self) -> str:
        """One line for logs, PLY comments and manifests, e.g. ``quadratic: f = 2*r^2 - 0.5``."""
        return f"{self.kind}: f = {FUNCTIONS[self.kind].written(self)}"


def _number(value: float) -> str:
    return f"{value:.6g}"


def _sum(terms: list[tuple[float, str]], constant: float) -> str:
    """``a*x + b*y + c`` with zero terms left out and negative ones subtracted; the constant is always shown."""
    parts = [(value, f"{_number(abs(value))}*{name}") for value, name in terms if value != 0.0]
    parts.append((constant, _number(abs(constant))))
    text = ("-" if parts[0][0] < 0 else "") + parts[0][1]
    for value, part in parts[1:]:
        text += f" {'-' if value < 0 else '+'} {part}"
    return text


@dataclass(frozen=True)
class FunctionKind:
    """One kind of distribution function: its equation, coefficients, formula and written form.

    uses: the coefficients (of alpha, beta, lam) a user may give; defaults: their values
    when not given; fixed: the values of the coefficients it does not use; formula(fn, r)
    -> f (n,) for r (n,); written(fn) -> the right-hand side as text.
    """

    equation: str
    uses: tuple[str, ...]
    defaults: dict
    fixed: dict
    formula: Callable[[DistributionFunction, np.ndarray], np.ndarray]
    written: Callable[[DistributionFunction], str]


#: The kinds of distribution function, by name (eq. 2-5 and user expressions).
FUNCTIONS: dict[str, FunctionKind] = {
    "constant": FunctionKind(
        "2", ("lam",), {"lam": 1.0}, {"alpha": 0.0, "beta": 0.0},
        lambda fn, r: np.full(r.shape, fn.lam),
        lambda fn: _number(fn.lam)),
    "linear": FunctionKind(
        "3", ("alpha", "lam"), {"alpha": 1.0, "lam": 0.0}, {"beta": 0.0},
        lambda fn, r: fn.alpha * r + fn.lam,
        lambda fn: _sum([(fn.alpha, "r")], fn.lam)),
    "quadratic": FunctionKind(
        "4", ("alpha", "beta", "lam"), {"alpha": 1.0, "beta": 0.0, "lam": 0.0}, {},
        lambda fn, r: (fn.alpha * r + fn.beta) * r + fn.lam,
        lambda fn: _sum([(fn.alpha, "r^2"), (fn.beta, "r")], fn.lam)),
    "sine": FunctionKind(
        "5", ("alpha", "beta", "lam"), {"alpha": 0.5, "beta": 2.0 * math.pi, "lam": 0.5}, {},
        lambda fn, r: fn.alpha * np.sin(fn.beta * r) + fn.lam,
        lambda fn: _sum([(fn.alpha, f"sin({_number(fn.beta)}*r)")], fn.lam)),
    "expression": FunctionKind(
        "-", (), {}, {},
        lambda fn, r: evaluate_expression(fn.expression or "", r),
        lambda fn: str(fn.expression)),
}
FUNCTION_KINDS = tuple(FUNCTIONS)
#: The coefficient names of :func:`make_function` as a user reads them.
_COEFFICIENT_NAMES = {"alpha": "alpha", "beta": "beta", "lam": "lambda"}


def finite(name: str, value) -> float:
    """``value`` as a finite float; InputError naming the parameter otherwise."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name}: must be a number, got {shown(value)}") from None
    if not math.isfinite(number):
        raise InputError(f"{name}: must be finite, got {shown(value)}")
    return number


def make_function(kind: str, alpha: float | None = None, beta: float | None = None,
                  lam: float | None = None, periods: float | None = None,
                  expression: str | None = None) -> DistributionFunction:
    """A :class:`DistributionFunction` with the kind's defaults filled in.

    Raises InputError for an unknown kind, non-finite coefficients, a coefficient the
    kind does not use (beta for linear...), ``periods`` (sine only) together with
    ``beta``, or an expression that does not parse or uses anything outside the whitelist.
    """
    name = str(kind).strip().lower()
    if name not in FUNCTIONS:
        raise InputError(f"kind: unknown distribution function {name!r} (choose from {', '.join(FUNCTION_KINDS)})")
    row = FUNCTIONS[name]
    if expression is not None and name != "expression":
        raise InputError(f"expression: only used with the 'expression' function, not {name!r}")
    if periods is not None and name != "sine":
        raise InputError(f"periods: only applies to the 'sine' function, not {name!r}")
    given = {key: finite(key, value) for key, value in (("alpha", alpha), ("beta", beta), ("lam", lam),
                                                          ("periods", periods)) if value is not None}
    stray = [key for key in ("alpha", "beta", "lam") if key in given and key not in row.uses]
    if stray:
        names = [_COEFFICIENT_NAMES[key] for key in stray]
        raise InputError(f"{stray[0]}: {' and '.join(names)} {'is' if len(names) == 1 else 'are'} not used by "
                         f"the {name} function (see its formula)")
    if name == "expression":
        if expression is None or not str(expression).strip():
            raise InputError("expression: the 'expression' function needs an expression in r, "
                             "e.g. '0.5 - 0.5*cos(2*pi*r)'")
        compile_expression(expression)
        return DistributionFunction("expression", expression=str(expression).strip())
    if "periods" in given:
        if "beta" in given:
            raise InputError("periods: give either beta or periods for the sine function, not both")
        given["beta"] = 2.0 * math.pi * given["periods"]
        if not math.isfinite(given["beta"]):
            raise InputError(f"periods: {shown(given['periods'])} periods make beta = 2 pi periods infinite")
    values = {**row.fixed, **row.defaults, **{key: given[key] for key in row.uses if key in given}}
    return DistributionFunction(name, alpha=values["alpha"], beta=values["beta"], lam=values["lam"])


def evaluate(func: DistributionFunction, r: np.ndarray) -> np.ndarray:
    """f(r) (n,) float64 for r (n,) in [0, 1], by the kind's formula (eq. 2-5); not clipped (eq. 1's blend clips).
    A float32 r gives a float32 f for the kinds of eq. 2-5 (the field interior's halftone needs f to 1/256).

    An expression that is undefined (NaN) at some r raises InputError naming that r.
    """
    row = FUNCTIONS.get(func.kind)
    if row is None:
        raise InputError(f"kind: unknown distribution function {func.kind!r}")
    r = np.asarray(r)
    r = r if r.dtype == np.float32 else r.astype(np.float64, copy=False)
    with np.errstate(all="ignore"):
        f = row.formula(func, r)
    bad = ~np.isfinite(f)
    if bad.any():
        at = float(r[bad].flat[0]) if r.shape == f.shape else float("nan")
        raise InputError(f"{_culprit(func, row)}: {func.describe()} gives f = {shown(float(f[bad].flat[0]))} at "
                         f"r = {at:.6g}; a material fraction must be a finite number")
    return f


def _culprit(func: DistributionFunction, row: FunctionKind) -> str:
    """The parameter to blame for a non-finite f: the expression, or the used coefficient of largest size."""
    if func.kind == "expression":
        return "expression"
    return max(row.uses, key=lambda name: abs(getattr(func, name)), default="kind")
