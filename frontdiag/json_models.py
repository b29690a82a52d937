"""The JSON documents printed with ``--json``, as pydantic models.

Every command a machine reads prints one of these documents, each with a ``schema`` field naming
its version (:mod:`frontdiag.schemas`). The JSON Schemas in ``docs/schemas/`` are generated from
these models (``python -m frontdiag.json_models docs/schemas``) and a test checks both that they
are current and that the commands' output validates against them.

Fields are only added within a version. Nested parts whose keys follow the data (per-topic
counts, per-metric statistics) are open objects; everything a CI script branches on (gate,
verdict counts, rule IDs, scores) is typed.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from frontdiag import schemas
from frontdiag.verdicts.model import Rule


class _Doc(BaseModel):
    model_config = ConfigDict(extra="forbid")


# --- analyze --------------------------------------------------------------------------------

class Gate(_Doc):
    exit_code: int = Field(description="0 passed, 1 a gate failed, 2 damaged input, 130 interrupted")
    passed: bool
    fail_on: Literal["warn", "fail", "never"]
    reasons: list[str]
    incomplete: str | None = Field(
        description="why the run did not reach the end of the recording (never passes)")


class ConditionCount(_Doc):
    frames: int
    share: float
    episodes: int


class RuleCount(_Doc):
    id: str
    condition: str
    severity: Literal["warn", "fail"]
    scope: Literal["frame", "run"]
    frames: int
    failed_gate: bool


class RunFindingDoc(_Doc):
    rule: str
    condition: str
    severity: Literal["warn", "fail"]
    fired: bool
    evaluated: bool = Field(description="false: the check could not run (not evaluated, not ok)")
    value: float | None
    message: str
    frames: list[int]


class NoPoseDoc(_Doc):
    frames: int = Field(description="rows on which the frontend estimated no motion")
    expected: int = Field(description="rows where a pose was expected (not a sensor's first "
                                      "frame, not a camera without intrinsics)")
    unnamed: int = Field(description="of the rows with no pose, those with verdict ok: no rule "
                                     "named a cause")
    statuses: dict[str, int] = Field(description="the rows with no pose by status")


class VerdictsDoc(_Doc):
    frontdiag: str
    frames: int
    verdicts: dict[Literal["ok", "warn", "fail"], int]
    no_pose: NoPoseDoc
    gate: Gate
    conditions: dict[str, ConditionCount]
    rules: list[RuleCount]
    episodes: list[dict[str, Any]] = Field(
        description="one object per episode, the columns of episodes.parquet")
    run_findings: list[RunFindingDoc]


class AnalyzeDoc(_Doc):
    """`frontdiag analyze --json`."""

    schema_: str = Field(alias="schema", default=schemas.ANALYZE_SCHEMA)
    input: dict[str, Any]
    topics: dict[str, Any]
    counts: dict[str, Any]
    notes: list[str]
    fault: str | None
    interrupted: bool
    written: list[str] = Field(description="every file this run wrote")
    sensors: dict[str, Any]
    verdicts: VerdictsDoc | None = None


# --- info -----------------------------------------------------------------------------------

class TopicDoc(_Doc):
    topic: str
    msgtype: str
    count: int | None
    rate_hz: float | None
    first_s: float | None
    last_s: float | None
    max_gap_s: float | None
    detail: str


class InfoDoc(_Doc):
    """`frontdiag info --json`."""

    schema_: str = Field(alias="schema", default=schemas.INFO_SCHEMA)
    path: str
    container: str = Field(default="", description="what the recording was read as: a ROS 1 "
                           "bag, split bags, a ROS 2 bag folder (and its compression), split "
                           "parts without metadata.yaml, MCAP, ...")
    backend: str
    duration_s: float | None
    start_ns: int | None
    end_ns: int | None
    topics: list[TopicDoc]
    analyze_would_use: dict[str, str | None] | None
    choice_error: str | None
    oddities: list[str]
    fault: str | None = Field(default=None, description="damage met while reading: the command "
                              "exits 2, the counts cover what was readable before it")


class InfoErrorDoc(_Doc):
    path: str
    error: str


class InfoFleetDoc(_Doc):
    """`frontdiag info FOLDER --json` on a folder of recordings: one `info` document each."""

    schema_: str = Field(alias="schema", default=schemas.INFO_FLEET_SCHEMA)
    folder: str
    recordings: list[InfoDoc]
    errors: list[InfoErrorDoc] = Field(description="recordings that could not be opened")


# --- explain --------------------------------------------------------------------------------

class ClauseDoc(_Doc):
    metric: str
    value: float | str | None
    unit: str
    test: str
    holds: bool
    rules_out: str | None
    in_table: bool = True
    """False where the table was written before this metric existed (re-run analyze)."""


class RuleOnRow(_Doc):
    id: str
    condition: str
    severity: Literal["warn", "fail"]
    title: str
    state: Literal["fired", "holds_not_persistent", "clear"]
    clauses: list[ClauseDoc]
    check: list[str]
    fix: str | None


class MetricOnRow(_Doc):
    name: str
    value: float | str | list[float] | None
    unit: str
    thresholds: list[str]


class ExplainDoc(_Doc):
    """`frontdiag explain RESULT --frame N --json`."""

    schema_: str = Field(alias="schema", default=schemas.EXPLAIN_SCHEMA)
    result: str
    frame: int
    sensor: str
    topic: str
    t_rel_s: float | None
    status: str = Field(description="whether the frontend could evaluate the frame")
    status_meaning: str
    verdict: Literal["ok", "warn", "fail"] = Field(description="what the rules found")
    conditions: list[str]
    frame_range: dict[str, int] = Field(description="first and last frame of this topic")
    also_on: list[str] = Field(default_factory=list,
                               description="other topics with a row of this frame (or time), "
                               "explained with --topic; with none given, the camera's row is "
                               "the one shown")
    rules: list[RuleOnRow]
    metrics: list[MetricOnRow]


# --- rules ----------------------------------------------------------------------------------

class RuleSummary(_Doc):
    id: str
    severity: Literal["warn", "fail"]
    condition: str
    sensor: Literal["camera", "lidar"]
    scope: Literal["frame", "run"]
    title: str
    file: str


class RulesListDoc(_Doc):
    """`frontdiag rules list --json`."""

    schema_: str = Field(alias="schema", default=schemas.RULES_LIST_SCHEMA)
    sources: list[str]
    rules: list[RuleSummary]


class RulesExplainDoc(_Doc):
    """`frontdiag rules explain ID --json`: the rule as loaded (after overrides)."""

    schema_: str = Field(alias="schema", default=schemas.RULES_EXPLAIN_SCHEMA)
    rule: Rule
    units: dict[str, str] = Field(description="unit of each metric the rule reads")


class RulesCheckDoc(_Doc):
    """`frontdiag rules check [DIR] --json`."""

    schema_: str = Field(alias="schema", default=schemas.RULES_CHECK_SCHEMA)
    dirs: list[str]
    valid: bool
    rules: int
    files: int
    problems: list[str]


# --- simulate --list ------------------------------------------------------------------------

class ScenarioDoc(_Doc):
    name: str
    summary: str
    labels: str
    default_seconds: float


class ScenariosDoc(_Doc):
    """`frontdiag simulate --list --json`."""

    schema_: str = Field(alias="schema", default=schemas.SCENARIOS_SCHEMA)
    scenarios: list[ScenarioDoc]


# --- eval -----------------------------------------------------------------------------------

class ConditionScoreDoc(_Doc):
    condition: str
    sensors: list[str]
    episodes: int
    episodes_found: int
    episode_recall: float | None
    episode_recall_ci95: list[float] | None = Field(
        default=None, description="95 % Wilson score interval of episode_recall [low, high]")
    frames_labelled: int
    frames_flagged: int
    true_positives: int
    false_positives: int
    frame_precision: float | None
    frame_recall: float | None
    frame_f1: float | None
    healthy_frames: int
    false_alarms: int
    false_alarm_rate: float | None
    false_alarm_rate_ci95: list[float] | None = Field(
        default=None, description="95 % Wilson score interval of false_alarm_rate [low, high]")


class EvalGate(_Doc):
    passed: bool
    reasons: list[str]


class ScoresDoc(_Doc):
    """The scores of one recording or of a pooled set (``frontdiag.scoring.EvalReport``)."""

    frames: int
    labelled_frames: int
    healthy_frames: int
    false_alarms: int
    false_alarm_rate: float | None
    false_alarm_rate_ci95: list[float] | None = Field(
        default=None, description="95 % Wilson score interval of false_alarm_rate [low, high]")
    unknown_predicted: list[str]
    conditions: list[ConditionScoreDoc]


class RecordingScoreDoc(ScoresDoc):
    """One recording's scores in a fleet's `frontdiag eval --json`."""

    recording: str


class EvalDoc(ScoresDoc):
    """`frontdiag eval --json`."""

    schema_: str = Field(alias="schema", default=schemas.EVAL_SCHEMA)
    gate: EvalGate
    recordings: list[RecordingScoreDoc] = []
    """A fleet's folder: each scored recording's own report (the fields above are pooled)."""
    not_scored: list[str] = []
    """A fleet's folder: recordings left out, with why (no labels beside them, not analysed)."""


DOCUMENTS: dict[str, type[BaseModel]] = {
    "analyze": AnalyzeDoc,
    "info": InfoDoc,
    "info-fleet": InfoFleetDoc,
    "explain": ExplainDoc,
    "rules-list": RulesListDoc,
    "rules-explain": RulesExplainDoc,
    "rules-check": RulesCheckDoc,
    "simulate-list": ScenariosDoc,
    "eval": EvalDoc,
}
"""File stem in docs/schemas/ -> model."""


def json_schema(name: str) -> dict[str, Any]:
    """The JSON Schema of one document, with its ``$id`` and title."""
    model = DOCUMENTS[name]
    out = model.model_json_schema(by_alias=True, mode="serialization")
    out = {"$schema": "https://json-schema.org/draft/2020-12/schema",
           "$id": f"{schemas.SCHEMA_BASE}/{name}.v{schemas.VERSION}.json", **out}
    out["properties"]["schema"]["const"] = schemas.schema_id(name)
    out.setdefault("required", [])
    if "schema" not in out["required"]:
        out["required"].insert(0, "schema")
    return out


def dump(doc: BaseModel) -> str:
    """A document as indented JSON (aliases applied, so the version field reads ``schema``)."""
    return doc.model_dump_json(by_alias=True, indent=2)


def emit(model: type[BaseModel], data: dict[str, Any]) -> str:
    """Validate plain data against a document model and return its JSON text."""
    return dump(model.model_validate(data))


def write_all(directory: Path) -> list[Path]:
    directory.mkdir(parents=True, exist_ok=True)
    out = []
    for name in DOCUMENTS:
        path = directory / f"{name}.json"
        path.write_text(json.dumps(json_schema(name), indent=2, ensure_ascii=False) + "\n")
        out.append(path)
    return out


if __name__ == "__main__":  # python -m frontdiag.json_models docs/schemas
    for p in write_all(Path(sys.argv[1] if len(sys.argv) > 1 else "docs/schemas")):
        print(p)
