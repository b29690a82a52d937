"""The shape of a rules file, validated with pydantic.

A rule is data: which condition it detects, how severe it is, the clauses (`metric op value`) and
named check it evaluates, an optional persistence window, and the text a user needs. Every
threshold carries a one-line reason. Nothing here is executed; the engine interprets it.
"""

from __future__ import annotations

import math
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

Severity = Literal["warn", "fail"]
SEVERITY_RANK: dict[str, int] = {"ok": 0, "warn": 1, "fail": 2}
FRACTION_KEYS = ("warn", "fail", "nopose")
"""Keys of --max-fraction and [run.max_fraction]: a severity, or the share of rows with no pose."""

ParamValue = int | float | str | list[float]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Clause(_Strict):
    """`metric op value`, optionally on |metric|; `key` names it for overrides (default: metric)."""

    metric: str
    op: str
    value: float | list[float] | None = None
    abs: bool = False
    key: str | None = None
    reason: str = Field(min_length=1)
    rules_out: str | None = None
    """A look-alike condition this clause rules out (shown by `frontdiag explain`)."""

    @property
    def name(self) -> str:
        return self.key or self.metric


class Param(_Strict):
    """A threshold or option of a named check, with the reason it has this value."""

    value: ParamValue
    reason: str = Field(min_length=1)


class Persistence(_Strict):
    """Keep a hit only where at least k of some n consecutive rows of its topic hit.

    With ``span_s``, the window also spans at least that many seconds of the topic's own frame
    rate: on a faster stream n grows to ``round(span_s * rate)`` rows and k in proportion
    (``window``), so a window means the same time at 10 Hz, 30 Hz or 200 Hz.
    """

    k: int = Field(ge=1)
    n: int = Field(ge=1)
    span_s: float | None = Field(default=None, ge=0)
    """0 or absent: the window is n rows at any frame rate."""
    reason: str = Field(min_length=1)

    @model_validator(mode="after")
    def _k_le_n(self) -> Persistence:
        if self.k > self.n:
            raise ValueError(f"persistence k={self.k} exceeds n={self.n}")
        return self

    def window(self, rate_hz: float) -> tuple[int, int]:
        """``(k, n)`` in rows for a stream at ``rate_hz`` (NaN or 0: the rows as written)."""
        if not self.span_s or not math.isfinite(rate_hz) or rate_hz <= 0:
            return self.k, self.n
        n = max(self.n, round(self.span_s * rate_hz))
        return -(-self.k * n // self.n), n

    def describe(self, rate_hz: float = float("nan")) -> str:
        """How a user reads the window, e.g. "3 of 5 consecutive rows (at least 0.33 s)"."""
        k, n = self.window(rate_hz)
        span = f" (at least {self.span_s:g} s)" if self.span_s else ""
        return f"{k} of {n} consecutive rows{span}"


class RuleText(_Strict):
    """What a user reads about a rule: symptom, revealing metric, values, look-alike, fixes."""

    symptom: str = Field(min_length=1)
    reveals: str = Field(min_length=1)
    """The metric that reveals it."""
    healthy: str = Field(min_length=1)
    broken: str = Field(min_length=1)
    distinguish: str = Field(min_length=1)
    """The value that separates it from its look-alikes."""
    fix: str = Field(min_length=1)
    wrong_fix: str = Field(min_length=1)
    source: str = Field(min_length=1)
    """Where the numbers come from: a section of docs/derivations.md, a paper, your notes."""


RULE_ID_PATTERN = r"^[A-Z][A-Z0-9]{1,15}(-[A-Z0-9]{1,15})*-\d{3}$"


def looks_like_rule_id(text: str) -> bool:
    """Whether ``text`` (any case) has the shape of a rule ID (FD-PLN-001, MY-001)."""
    import re

    return re.match(RULE_ID_PATTERN, text.upper()) is not None
"""NAMESPACE(-AREA)-NNN: the shipped rules use FD-XXX-NNN; a team's own rules take their own
namespace (MY-001, ACME-DOCK-002), so they never collide with a shipped ID."""


class Rule(_Strict):
    id: str = Field(pattern=RULE_ID_PATTERN)
    title: str = Field(min_length=1)
    condition: str
    severity: Severity
    severity_reason: str = Field(min_length=1)
    scope: Literal["frame", "run"] = "frame"
    sensor: Literal["camera", "lidar"]
    combine: Literal["all", "any"] = "all"
    when: tuple[Clause, ...] = ()
    check: str | None = None
    params: dict[str, Param] = Field(default_factory=dict)
    persistence: Persistence | None = None
    text: RuleText
    area: str = ""
    """File stem the rule came from (filled by the loader)."""

    @model_validator(mode="after")
    def _has_logic(self) -> Rule:
        if not self.when and self.check is None:
            raise ValueError("a rule needs `when` clauses, a `check`, or both")
        if self.scope == "run" and (self.when or self.check is None):
            raise ValueError("a run-scope rule is exactly one named `check` and no `when`")
        names = [c.name for c in self.when]
        dup = {n for n in names if names.count(n) > 1} | (set(names) & set(self.params))
        if dup:
            raise ValueError(f"threshold names used twice (give clauses a `key`): {sorted(dup)}")
        return self

    def thresholds(self) -> dict[str, Any]:
        """Every overridable threshold of the rule by name: clause values and check params."""
        out: dict[str, Any] = {c.name: c.value for c in self.when}
        out.update(self.param_values())
        return out

    def param_values(self) -> dict[str, Any]:
        """The check's params by name, as the check functions take them."""
        return {k: p.value for k, p in self.params.items()}

    def param(self, name: str) -> Any:
        return self.params[name].value


class Tolerance(_Strict):
    value: float = Field(ge=0)
    reason: str = Field(min_length=1)


class EpisodeLimit(_Strict):
    """A run-level gate: an episode of this condition longer than max_s fails at `severity`."""

    max_s: float = Field(gt=0)
    severity: Severity = "fail"
    reason: str = Field(min_length=1)


class EpisodeConfig(_Strict):
    max_gap_frames: int = Field(default=1, ge=0)
    reason: str = "one clean row inside a run of hits is threshold noise, not a recovery"


class BaselineConfig(_Strict):
    metric_median_rel_tol: dict[str, Tolerance] = Field(default_factory=dict)
    """Relative change of a metric's median (in its worse direction) that counts as a regression."""
    condition_share_abs_tol: Tolerance = Tolerance(
        value=0.02, reason="two percentage points of frames is larger than run-to-run jitter")


class RunConfig(_Strict):
    episodes: EpisodeConfig = EpisodeConfig()
    max_fraction: dict[str, Tolerance] = Field(default_factory=dict)
    """Default --max-fraction gates by severity (share of analysed rows at or above it)."""
    episode_limits: dict[str, EpisodeLimit] = Field(default_factory=dict)
    baseline: BaselineConfig = BaselineConfig()
