"""The loop-closure rules (rules/loops/loops.toml), validated with the shapes of verdicts/.

Loop rules reuse :class:`~frontdiag.verdicts.model.Param` and
:class:`~frontdiag.verdicts.model.RuleText`; what differs from the per-frame rules is what they
evaluate (a named statistic of a loop, not a metric of a frame).
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from frontdiag.errors import RuleError
from frontdiag.verdicts.loader import default_rules_dir
from frontdiag.verdicts.model import Param, RuleText, Severity

Statistic = Literal["chi2", "pcm", "map", "untestable", "stiffness"]


class LoopRule(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    id: str = Field(pattern=r"^FD-LOP-\d{3}$")
    title: str = Field(min_length=1)
    severity: Severity
    severity_reason: str = Field(min_length=1)
    statistic: Statistic
    params: dict[str, Param] = Field(default_factory=dict)
    text: RuleText

    def param(self, name: str) -> Any:
        return self.params[name].value


class LoopRules(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    about: str = ""
    rule: tuple[LoopRule, ...]
    source: str = ""

    def by_statistic(self, stat: str) -> LoopRule:
        for r in self.rule:
            if r.statistic == stat:
                return r
        raise RuleError(self.source, f"no loop rule with statistic {stat!r}")

    def optional(self, stat: str) -> LoopRule | None:
        """The rule of ``stat``, or None where the rules file has none (an optional check)."""
        return next((r for r in self.rule if r.statistic == stat), None)

    def get(self, rule_id: str) -> LoopRule:
        for r in self.rule:
            if r.id == rule_id:
                return r
        raise RuleError(self.source, f"unknown loop rule {rule_id!r}")


def default_loop_rules_file() -> Path:
    return default_rules_dir() / "loops" / "loops.toml"


def load_loop_rules(path: Path | None = None) -> LoopRules:
    """Read and validate the loop rules (default: the shipped rules/loops/loops.toml)."""
    path = Path(path) if path is not None else default_loop_rules_file()
    try:
        data = tomllib.loads(path.read_text())
    except OSError as exc:
        raise RuleError(path, f"cannot read ({exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise RuleError(path, f"not valid TOML ({exc})") from None
    try:
        rules = LoopRules.model_validate({**data, "source": str(path)})
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = ".".join(str(p) for p in err["loc"])
        raise RuleError(path, f"{loc}: {err['msg']}") from None
    for stat in ("chi2", "pcm", "map", "untestable"):
        rules.by_statistic(stat)
    return rules
