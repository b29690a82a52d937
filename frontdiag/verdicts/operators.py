"""The closed set of operators a rule clause may use: one plain dict, nothing passed to eval.

Every operator maps a float column (NaN where not computable) and the clause value to a boolean
mask. A comparison with NaN is False, so a frame whose metric could not be computed never fires a
threshold; `is_nan` / `not_nan` test computability itself.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Operator:
    symbol: str
    arity: int
    """0: no value; 1: one number; 2: a [low, high] pair."""
    apply: Callable[[np.ndarray, object], np.ndarray]


def _pair(v: object) -> tuple[float, float]:
    seq = list(v)  # type: ignore[call-overload]
    return float(seq[0]), float(seq[1])


def _between(x: np.ndarray, v: object) -> np.ndarray:
    lo, hi = _pair(v)
    return (x >= lo) & (x <= hi)


def _outside(x: np.ndarray, v: object) -> np.ndarray:
    lo, hi = _pair(v)
    return (x < lo) | (x > hi)


OPERATORS: dict[str, Operator] = {op.symbol: op for op in [
    Operator("<", 1, lambda x, v: x < v),
    Operator("<=", 1, lambda x, v: x <= v),
    Operator(">", 1, lambda x, v: x > v),
    Operator(">=", 1, lambda x, v: x >= v),
    Operator("==", 1, lambda x, v: x == v),
    Operator("!=", 1, lambda x, v: ~np.isnan(x) & (x != v)),
    Operator("between", 2, _between),
    Operator("outside", 2, _outside),
    Operator("is_nan", 0, lambda x, v: np.isnan(x)),
    Operator("not_nan", 0, lambda x, v: ~np.isnan(x)),
]}


def check_value(op: str, value: object) -> str | None:
    """Why `value` does not suit operator `op`, or None when it does."""
    spec = OPERATORS.get(op)
    if spec is None:
        return f"unknown operator {op!r} (known: {', '.join(OPERATORS)})"
    if spec.arity == 0:
        return None if value is None else f"operator {op!r} takes no value"
    if spec.arity == 1:
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        return None if ok else f"operator {op!r} needs one number, got {value!r}"
    ok = (isinstance(value, list) and len(value) == 2
          and all(isinstance(v, int | float) for v in value) and value[0] <= value[1])
    return None if ok else f"operator {op!r} needs [low, high] with low <= high, got {value!r}"


def apply(op: str, column: np.ndarray, value: object, *, use_abs: bool = False) -> np.ndarray:
    """Evaluate one clause over a float column."""
    x = np.abs(column) if use_abs else column
    with np.errstate(invalid="ignore"):
        return np.asarray(OPERATORS[op].apply(x, value), dtype=bool)


def describe(metric: str, op: str, value: object, *, use_abs: bool = False) -> str:
    """`|d_mean_intensity| > 8` style text for a clause."""
    m = f"|{metric}|" if use_abs else metric
    if OPERATORS[op].arity == 0:
        return f"{m} {op}"
    if OPERATORS[op].arity == 2:
        lo, hi = _pair(value)
        return f"{m} {op} [{_num(lo)}, {_num(hi)}]"
    return f"{m} {op} {_num(value)}"


def _num(v: object) -> str:
    if isinstance(v, float):
        return f"{v:g}"
    return str(v)
