"""Options shared by ``color``, ``slice`` and ``info``, declared once, and the map from library parameters to
flags.

The library's errors begin with the parameter at fault (``alpha: must be finite``);
:func:`flags` rewrites that prefix to the option the user typed (``--alpha: ...``).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import click

from heoslice.errors import InputError
from heoslice.material import FUNCTIONS, DistributionFunction, make_function
from heoslice.mesh import Mesh, scaled
from heoslice.pipeline import check_scale

#: Library parameter of :func:`heoslice.material.make_function` -> its option.
FUNCTION_FLAGS = {"alpha": "--alpha", "beta": "--beta", "lam": "--lambda", "periods": "--periods",
                  "expression": "--expr"}


@contextmanager
def flags(mapping: dict[str, str]) -> Iterator[None]:
    """Re-raise an InputError whose message starts with ``PARAMETER:`` (or ``A, B:``) with those parameters'
    options instead."""
    try:
        yield
    except InputError as err:
        named, sep, rest = str(err).partition(": ")
        parameters = named.split(", ")
        if sep and all(parameter in mapping for parameter in parameters):
            raise InputError(f"{', '.join(mapping[p] for p in parameters)}: {rest}", exit_code=err.exit_code) from None
        raise


@contextmanager
def option(name: str) -> Iterator[None]:
    """Put ``name`` (an option) in front of any InputError raised inside."""
    try:
        yield
    except InputError as err:
        raise InputError(f"{name}: {err}", exit_code=err.exit_code) from None


def _defaults(coefficient: str) -> str:
    """The defaults of one coefficient over the function kinds that use it, e.g. 'linear 1, sine 0.5'."""
    shown = [f"{kind} {row.defaults[coefficient]:.6g}" for kind, row in FUNCTIONS.items()
             if coefficient in row.uses]
    if coefficient == "beta":
        shown = [part if not part.startswith("sine") else "sine 2 pi periods" for part in shown]
    return ", ".join(shown)


def _equations(coefficient: str) -> str:
    numbers = [row.equation for row in FUNCTIONS.values() if coefficient in row.uses]
    return f"eq. {numbers[0]}-{numbers[-1]}" if len(numbers) > 1 else f"eq. {numbers[0]}"


def function_options(command):
    """Add --alpha, --beta, --lambda, --periods and --expr (the coefficients of eq. 2-5) to a click command."""
    declared = [
        click.option("--alpha", type=float, default=None,
                     help=f"alpha of {_equations('alpha')} [default: {_defaults('alpha')}]."),
        click.option("--beta", type=float, default=None,
                     help=f"beta of {_equations('beta')} [default: {_defaults('beta')}]."),
        click.option("--lambda", "lam", type=float, default=None,
                     help=f"lambda of {_equations('lam')} [default: {_defaults('lam')}]."),
        click.option("--periods", type=float, default=None,
                     help="Sine periods over r = 0..1, instead of --beta (beta = 2 pi periods) [default: 1]."),
        click.option("--expr", "--expression", "expression", default=None, metavar="FORMULA",
                     help="f as a formula in r for the expression function, e.g. \"0.5 - 0.5*cos(2*pi*r)\" "
                          "(+ - * / **, pi, e, sin cos exp log sqrt abs min max clip...)."),
    ]
    for decorate in reversed(declared):
        command = decorate(command)
    return command


def function_from_options(kind_flag: str, kind: str, alpha: float | None, beta: float | None, lam: float | None,
                          periods: float | None, expression: str | None) -> DistributionFunction:
    """The distribution function the options ask for; errors name the option (``kind_flag`` for the kind)."""
    if kind in ("expr", "formula"):
        kind = "expression"
    with flags({**FUNCTION_FLAGS, "kind": kind_flag}):
        return make_function(kind, alpha=alpha, beta=beta, lam=lam, periods=periods, expression=expression)


#: ``--scale`` of every command that reads a model (slice, color, info): its coordinates times this, in mm.
scale_option = click.option("--scale", type=float, default=1.0, show_default=True,
                            help="Multiply coordinates by this (1000 for a model in metres).")


def apply_scale(mesh: Mesh, scale: float) -> Mesh:
    """``mesh`` with its coordinates multiplied by ``scale`` (the --scale option; range errors name it)."""
    if scale == 1.0:
        return mesh
    with flags({"scale": "--scale"}):
        check_scale(scale, mesh.bounds)
        return scaled(mesh, scale)
