"""The numeric thresholds the rules read, per metric: what the plots (MCAP and HTML) draw.

Read from the ruleset (clauses ``metric op value`` and the named checks' metric parameters), so a
rule added or overridden is drawn without touching the renderers.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from frontdiag.verdicts.checks import CHECKS
from frontdiag.verdicts.loader import Ruleset


@dataclass(frozen=True)
class Threshold:
    metric: str
    rule: str
    sensor: str
    severity: str
    value: float
    label: str  # e.g. "FD-CAM-001 entropy_norm < 0.6"

    @property
    def field(self) -> str:
        """A ROS-style field name: ``fd_cam_001_entropy_norm`` (``_neg`` for a -|x| bound)."""
        base = f"{self.rule}_{self.metric}".lower()
        suffix = "_neg" if self.value < 0 and "|" in self.label else ""
        return re.sub(r"[^a-z0-9]+", "_", base).strip("_") + suffix


def _numbers(value: object) -> list[float]:
    if isinstance(value, bool) or value is None:
        return []
    if isinstance(value, int | float):
        return [float(value)]
    if isinstance(value, list | tuple):
        return [float(v) for v in value if isinstance(v, int | float) and not isinstance(v, bool)]
    return []


def rule_thresholds(ruleset: Ruleset) -> list[Threshold]:
    """Every numeric threshold of the frame rules, one entry per drawn line."""
    out: list[Threshold] = []
    seen: set[tuple[str, str, float]] = set()

    def add(metric: str, rule_id: str, sensor: str, severity: str, value: float,
            label: str) -> None:
        key = (metric, rule_id, value)
        if key not in seen:
            seen.add(key)
            out.append(Threshold(metric, rule_id, sensor, severity, value, label))

    for rule in ruleset.frame_rules:
        for c in rule.when:
            m = f"|{c.metric}|" if c.abs else c.metric
            for v in _numbers(c.value):
                add(c.metric, rule.id, rule.sensor, rule.severity, v, f"{rule.id} {m} {c.op} {v:g}")
                if c.abs and v > 0:
                    add(c.metric, rule.id, rule.sensor, rule.severity, -v,
                        f"{rule.id} {m} {c.op} {v:g}")
        chk = CHECKS.get(rule.check or "")
        if chk is None:
            continue
        for name, metric in chk.param_metrics.items():
            if name in rule.params:
                for v in _numbers(rule.params[name].value):
                    add(metric, rule.id, rule.sensor, rule.severity, v,
                        f"{rule.id} {metric}: {name} = {v:g}")
    return out
