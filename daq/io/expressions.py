"""Arithmetic over a file's variables for ``daq import --map CHANNEL=EXPR``, without Python's eval.

Why not eval: a map comes from a command line or a shared script, and a recording's attributes keep it;
``eval`` of such text runs anything (``__import__('os').remove(...)``). The text is parsed by ``ast``
(parsing runs nothing) and the tree is walked here, allowing only numbers, names of the file's variables,
``+ - * / ** %``, unary signs, parentheses and a short list of numpy functions. Anything else (attribute
access, subscripts, calls to other names, comparisons, lambdas, strings) is one InputError naming the
construct.

Variable names as files write them: MATLAB struct fields (``run.force``), TDMS ``group/channel``, CSV
headers with spaces (``Force (N)``). Such a name is written in backticks (`` `Force (N)`*9.81 ``), or
plainly when it is one of the file's names: before parsing, the file's non-identifier names are replaced,
longest first, where they stand alone (not inside a longer word), so ``run/x1*1e-3`` reads the variable
``run/x1`` when the file has it and divides ``run`` by ``x1`` otherwise.
"""

from __future__ import annotations

import ast
import keyword
import operator
import re
from collections.abc import Callable, Mapping

import numpy as np

from daq.errors import InputError

FUNCTIONS: dict[str, Callable[..., np.ndarray]] = {
    "abs": np.abs, "sqrt": np.sqrt, "exp": np.exp, "log": np.log, "log10": np.log10,
    "sin": np.sin, "cos": np.cos, "tan": np.tan, "arctan2": np.arctan2, "deg2rad": np.deg2rad,
    "rad2deg": np.rad2deg, "min": np.minimum, "max": np.maximum,
}
CONSTANTS = {"pi": np.pi}
_BINARY = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv,
           ast.Pow: operator.pow, ast.Mod: operator.mod}
_UNARY = {ast.USub: operator.neg, ast.UAdd: operator.pos}
_IDENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_BACKTICK = re.compile(r"`([^`]*)`")


def _placeholder(i: int) -> str:
    return f"__var{i}__"


def _substitute(text: str, names: list[str]) -> tuple[str, dict[str, str]]:
    """Backticked names and the file's non-identifier names -> placeholders; returns (text, placeholder->name)."""
    alias: dict[str, str] = {}

    def take(name: str) -> str:
        key = _placeholder(len(alias))
        alias[key] = name
        return key

    text = _BACKTICK.sub(lambda m: take(m.group(1)), text)
    for name in sorted((n for n in names if not _IDENT.match(n)), key=len, reverse=True):
        pattern = r"(?<![A-Za-z0-9_.])" + re.escape(name) + r"(?![A-Za-z0-9_])"
        text = re.sub(pattern, lambda _m, n=name: take(n), text)
    return text, alias


class Expression:
    """One parsed map expression; ``names`` are the variables it reads."""

    def __init__(self, text: str, tree: ast.Expression, alias: dict[str, str], source: str, field: str):
        self.text, self._tree, self._alias, self._source, self._field = text, tree, alias, source, field
        self.names = sorted({self._name(n.id) for n in ast.walk(tree) if isinstance(n, ast.Name)}
                            - set(FUNCTIONS) - set(CONSTANTS))

    @classmethod
    def parse(cls, text: str, variables: list[str], source: str, field: str) -> Expression:
        """Parse ``text`` against the file's variable names; one InputError (``source``, ``field``) on a
        syntax error or a construct outside the allowed arithmetic."""
        if not text.strip():
            raise InputError(source, field, "empty expression")
        subst, alias = _substitute(text, variables)
        try:
            tree = ast.parse(subst.strip(), mode="eval")
        except SyntaxError as exc:
            raise InputError(source, field, f"syntax error in {text!r} at column {exc.offset}: {exc.msg}") from None
        expr = cls(text, tree, alias, source, field)
        for node in ast.walk(tree):
            expr._check(node)
        return expr

    def _name(self, ident: str) -> str:
        return self._alias.get(ident, ident)

    def _forbidden(self, what: str) -> InputError:
        allowed = "numbers, variables, + - * / ** %, parentheses, " + ", ".join(FUNCTIONS)
        return InputError(self._source, self._field, f"{what} is not allowed in {self.text!r} (allowed: {allowed})")

    def _check(self, node: ast.AST) -> None:
        if isinstance(node, (ast.Expression, ast.Load, *_BINARY, *_UNARY)):
            return
        if isinstance(node, ast.BinOp):
            if type(node.op) not in _BINARY:
                raise self._forbidden(f"operator {type(node.op).__name__}")
        elif isinstance(node, ast.UnaryOp):
            if type(node.op) not in _UNARY:
                raise self._forbidden(f"operator {type(node.op).__name__}")
        elif isinstance(node, ast.Constant):
            if isinstance(node.value, bool) or not isinstance(node.value, (int, float)):
                raise self._forbidden(f"the constant {node.value!r}")
        elif isinstance(node, ast.Call):
            if not isinstance(node.func, ast.Name) or node.func.id not in FUNCTIONS or node.keywords:
                name = node.func.id if isinstance(node.func, ast.Name) else ast.unparse(node.func)
                raise self._forbidden(f"a call of {self._name(name)!r}")
        elif isinstance(node, ast.Name):
            if node.id.startswith("__") and node.id not in self._alias or keyword.iskeyword(node.id):
                raise self._forbidden(f"the name {node.id!r}")
        else:
            raise self._forbidden(f"{type(node).__name__} ({ast.unparse(node)!r})")

    def evaluate(self, variables: Mapping[str, np.ndarray | float], size: int) -> np.ndarray:
        """The expression over the file's variables, as float64 of ``size`` samples (a constant is repeated).
        A name the file does not hold is one InputError listing what it has."""
        missing = [n for n in self.names if n not in variables]
        if missing:
            have = ", ".join(sorted(variables)) or "nothing"
            raise InputError(self._source, self._field, f"no variable {missing[0]!r} in the file (it has: {have})")
        try:
            with np.errstate(all="ignore"):  # a division by zero gives inf, as in MATLAB; the fit sees it
                value = self._eval(self._tree.body, variables)
        except (TypeError, ValueError) as exc:  # a function with the wrong arguments, shapes that do not match
            raise InputError(self._source, self._field, f"cannot evaluate {self.text!r}: {exc}") from None
        out = np.broadcast_to(np.asarray(value, dtype=np.float64), (size,)) if np.ndim(value) == 0 else \
            np.asarray(value, dtype=np.float64)
        if out.shape != (size,):
            raise InputError(self._source, self._field, f"{self.text!r} has {out.size} samples, t has {size}")
        return np.array(out)

    def _eval(self, node: ast.AST, env: Mapping[str, np.ndarray | float]) -> np.ndarray | float:
        if isinstance(node, ast.Constant):
            return float(node.value)
        if isinstance(node, ast.Name):
            name = self._name(node.id)
            return CONSTANTS[name] if name in CONSTANTS and name not in env else env[name]
        if isinstance(node, ast.BinOp):
            return _BINARY[type(node.op)](self._eval(node.left, env), self._eval(node.right, env))
        if isinstance(node, ast.UnaryOp):
            return _UNARY[type(node.op)](self._eval(node.operand, env))
        assert isinstance(node, ast.Call) and isinstance(node.func, ast.Name)  # checked by parse
        return FUNCTIONS[node.func.id](*(self._eval(a, env) for a in node.args))
