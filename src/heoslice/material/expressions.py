"""Distribution functions written as formulas in r: parsed with :mod:`ast`, never ``eval``'ed.

An expression may use numbers, ``r``, the constants ``pi`` and ``e``, ``+ - * / **``,
unary minus and the numpy functions of :data:`EXPRESSION_FUNCTIONS`; a small interpreter
walks the checked tree, vectorised over r. Errors name the parameter ``expression``.
"""

from __future__ import annotations

import ast
import math

import numpy as np

from heoslice.errors import InputError

#: Functions an expression may call: name -> (numpy function, number of arguments).
EXPRESSION_FUNCTIONS = {
    "sin": (np.sin, 1), "cos": (np.cos, 1), "tan": (np.tan, 1),
    "arcsin": (np.arcsin, 1), "arccos": (np.arccos, 1), "arctan": (np.arctan, 1),
    "sinh": (np.sinh, 1), "cosh": (np.cosh, 1), "tanh": (np.tanh, 1),
    "exp": (np.exp, 1), "log": (np.log, 1), "log2": (np.log2, 1), "log10": (np.log10, 1),
    "sqrt": (np.sqrt, 1), "abs": (np.abs, 1), "floor": (np.floor, 1), "ceil": (np.ceil, 1),
    "round": (np.round, 1), "sign": (np.sign, 1),
    "min": (np.minimum, 2), "max": (np.maximum, 2), "clip": (np.clip, 3),
}
EXPRESSION_CONSTANTS = {"pi": math.pi, "e": math.e}
MAX_CHARS = 1000
MAX_NODES = 500
_BINARY = {ast.Add: np.add, ast.Sub: np.subtract, ast.Mult: np.multiply,
           ast.Div: np.divide, ast.Pow: np.power}
_ALLOWED = (ast.Expression, ast.BinOp, ast.UnaryOp, ast.Constant, ast.Name, ast.Call, ast.Load,
            ast.UAdd, ast.USub, *_BINARY)


def _refuse(problem: str) -> InputError:
    return InputError(f"expression: {problem}")


def compile_expression(text: str) -> ast.Expression:
    """Parse and check an expression in r; raise InputError naming what is not allowed."""
    text = str(text)
    if len(text) > MAX_CHARS:
        raise _refuse(f"longer than {MAX_CHARS} characters")
    foreign = next((char for char in text if not char.isascii()), None)
    if foreign is not None:  # Python would read 'ｒ' as r (NFKC), and the PLY header is ASCII
        raise _refuse(f"{text!r} holds the non-ASCII character {foreign!r} (U+{ord(foreign):04X}); write the "
                      "formula in ASCII: r, pi, e, + - * / **, sin cos exp ...")
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except (SyntaxError, ValueError, RecursionError, MemoryError) as err:
        detail = getattr(err, "msg", None) or type(err).__name__
        raise _refuse(f"{text!r} does not parse ({detail})") from None
    nodes = list(ast.walk(tree))
    if len(nodes) > MAX_NODES:
        raise _refuse(f"{text!r} is too complex (more than {MAX_NODES} parts)")
    for node in nodes:
        _check_node(node, text)
    called = {id(node.func) for node in nodes if isinstance(node, ast.Call)}
    for node in nodes:
        if isinstance(node, ast.Name) and node.id in EXPRESSION_FUNCTIONS and id(node) not in called:
            raise _refuse(f"{text!r}: {node.id!r} is a function, call it with ()")
    return tree


def _check_node(node: ast.AST, text: str) -> None:
    """Refuse every AST node outside the whitelist (``^``, Python's exclusive or, as the power it was meant as)."""
    if isinstance(node, ast.BitXor):
        raise _refuse(f"{text!r}: ^ is not a power here, use ** (r**2 for r squared)")
    if not isinstance(node, _ALLOWED):
        raise _refuse(f"{text!r}: {type(node).__name__.lower()} is not allowed "
                      "(use numbers, r, pi, e, + - * / ** and functions like sin, exp, clip)")
    if isinstance(node, ast.Constant) and (isinstance(node.value, bool)
                                           or not isinstance(node.value, (int, float))):
        raise _refuse(f"{text!r}: only numbers are allowed as constants, not {node.value!r}")
    if isinstance(node, ast.Name) and node.id != "r" and node.id not in EXPRESSION_CONSTANTS \
            and node.id not in EXPRESSION_FUNCTIONS:
        raise _refuse(f"{text!r}: unknown name {node.id!r} (the variable is r; constants pi, e)")
    if isinstance(node, ast.Call):
        if not isinstance(node.func, ast.Name) or node.func.id not in EXPRESSION_FUNCTIONS:
            name = node.func.id if isinstance(node.func, ast.Name) else ast.unparse(node.func)
            raise _refuse(f"{text!r}: unknown function {name!r} "
                          f"(allowed: {', '.join(sorted(EXPRESSION_FUNCTIONS))})")
        arity = EXPRESSION_FUNCTIONS[node.func.id][1]
        if node.keywords or len(node.args) != arity:
            raise _refuse(f"{text!r}: {node.func.id}() takes {arity} argument(s)")


def evaluate_expression(text: str, r: np.ndarray) -> np.ndarray:
    """Vectorised value (n,) float64 of a checked expression at every r (n,); NaN anywhere is an InputError."""
    tree = compile_expression(text)

    def value(node: ast.AST):
        if isinstance(node, ast.Expression):
            return value(node.body)
        if isinstance(node, ast.Constant):
            return np.float64(node.value)
        if isinstance(node, ast.Name):
            if node.id == "r":
                return r
            return np.float64(EXPRESSION_CONSTANTS[node.id])
        if isinstance(node, ast.UnaryOp):
            operand = value(node.operand)
            return -operand if isinstance(node.op, ast.USub) else +operand
        if isinstance(node, ast.BinOp):
            return _BINARY[type(node.op)](value(node.left), value(node.right))
        function = EXPRESSION_FUNCTIONS[node.func.id][0]
        return function(*(value(arg) for arg in node.args))

    with np.errstate(all="ignore"):
        try:
            result = np.broadcast_to(np.asarray(value(tree), dtype=np.float64), r.shape).copy()
        except RecursionError:
            raise _refuse(f"{text!r} is nested too deeply") from None
    bad = np.isnan(result)
    if bad.any():
        raise _refuse(f"{text!r} is undefined (NaN) at r = {float(r[bad].flat[0]):.6g}")
    return result
