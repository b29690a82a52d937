"""One frame explained: every rule's clauses against the row's values, and the look-alikes ruled out.

`explain_row` returns plain data; `frontdiag explain` renders it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from frontdiag.metrics import METRICS
from frontdiag.verdicts.checks import CHECKS
from frontdiag.verdicts.engine import Verdicts, rule_mask, topic_groups
from frontdiag.verdicts.model import Rule
from frontdiag.verdicts.operators import apply, describe


@dataclass(frozen=True)
class ClauseLine:
    metric: str
    unit: str
    value: float
    test: str
    holds: bool
    reason: str
    rules_out: str | None


@dataclass(frozen=True)
class RuleExplanation:
    rule: Rule
    fired: bool
    raw: bool
    """All clauses and the check hold on this row (before persistence)."""
    clauses: list[ClauseLine]
    check_lines: list[str] = field(default_factory=list)


def _value(row: Mapping[str, Any], metric: str) -> float:
    try:
        return float(row.get(metric, math.nan))
    except (TypeError, ValueError):
        return math.nan


def _raw_hits(result: Verdicts, rule: Rule, position: int) -> tuple[bool, dict[str, Any]]:
    """Whether the rule's clauses and check hold on the row, read within its topic's rows, and
    the values the rule's check derives for the row from its neighbours."""
    for _topic, pos in topic_groups(result.table, rule.sensor):
        where = np.flatnonzero(pos == position)
        if where.size:
            rows = result.table.iloc[pos]
            raw = bool(rule_mask(rule, rows)[where[0]])
            ctx: dict[str, Any] = {}
            chk = CHECKS.get(rule.check or "")
            if chk is not None and chk.context is not None:
                params = rule.param_values()
                ctx = chk.context(rows.reset_index(drop=True), params).iloc[where[0]].to_dict()
            return raw, ctx
    return False, {}


def explain_row(result: Verdicts, position: int) -> list[RuleExplanation]:
    """How every rule for the row's sensor reads row `position` of result.table."""
    row = {str(k): v for k, v in result.table.iloc[position].to_dict().items()}
    sensor = str(row.get("sensor", "camera"))
    out = []
    for rule in result.ruleset.frame_rules:
        if rule.sensor != sensor:
            continue
        clauses = []
        for c in rule.when:
            v = _value(row, c.metric)
            holds = bool(apply(c.op, np.array([v]), c.value, use_abs=c.abs)[0])
            m = METRICS.get(c.metric)
            clauses.append(ClauseLine(c.metric, m.unit if m else "", v,
                                      describe(c.metric, c.op, c.value, use_abs=c.abs), holds,
                                      c.reason, c.rules_out))
        raw, ctx = _raw_hits(result, rule, position)
        lines: list[str] = []
        if rule.check is not None:
            chk = CHECKS[rule.check]
            if chk.explain is not None:
                lines = chk.explain({**row, **ctx},
                                    rule.param_values())
        fired = bool(result.hits[rule.id][position]) if rule.id in result.hits else False
        out.append(RuleExplanation(rule, fired, raw, clauses, lines))
    return out
