"""Machine-readable summary of verdicts and the gate (`--json`)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from frontdiag import __version__
from frontdiag.conditions import CONDITION_SENSORS, CONDITIONS
from frontdiag.verdicts.engine import Verdicts
from frontdiag.verdicts.gate import GateResult


def plain(value: Any) -> Any:
    """numpy / pandas scalars and containers -> JSON types (NaN -> None)."""
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple | np.ndarray):
        return [plain(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if value is pd.NA or value is pd.NaT:
        return None
    return value


def episode_records(result: Verdicts) -> list[dict[str, Any]]:
    return [plain({str(k): v for k, v in rec.items()
                   if not (str(k).startswith("peak_") and isinstance(v, float) and math.isnan(v))})
            for rec in result.episodes.to_dict(orient="records")]


def condition_counts(result: Verdicts) -> dict[str, dict[str, Any]]:
    t = result.table
    out: dict[str, dict[str, Any]] = {}
    for cond in CONDITIONS:
        rows = t[t["sensor"].isin(CONDITION_SENSORS[cond])] if "sensor" in t.columns else t
        frames = int(rows["conditions"].map(lambda c, cond=cond: cond in c).sum())
        eps = result.episodes
        n_eps = int((eps["condition"] == cond).sum()) if not eps.empty else 0
        out[cond] = {"frames": frames, "share": frames / len(rows) if len(rows) else 0.0,
                     "episodes": n_eps}
    return out


def to_json(result: Verdicts, gate_result: GateResult) -> dict[str, Any]:
    """Everything a CI job needs, as plain JSON types."""
    from frontdiag.verdicts.gate import no_pose

    t = result.table
    verdicts = t["verdict"].value_counts()
    return plain({
        "frontdiag": __version__,
        "frames": len(t),
        "verdicts": {k: int(verdicts.get(k, 0)) for k in ("ok", "warn", "fail")},
        "no_pose": no_pose(t).as_dict(),
        "gate": {"exit_code": gate_result.exit_code, "passed": gate_result.passed,
                 "fail_on": gate_result.fail_on, "reasons": gate_result.reasons,
                 "incomplete": gate_result.incomplete},
        "conditions": condition_counts(result),
        "rules": [{"id": r.id, "condition": r.condition, "severity": r.severity,
                   "scope": r.scope, "frames": result.rule_frames(r.id),
                   "failed_gate": r.id in gate_result.failed_rules}
                  for r in result.ruleset.rules],
        "episodes": episode_records(result),
        "run_findings": [{"rule": f.rule, "condition": f.condition, "severity": f.severity,
                          "fired": f.fired, "evaluated": f.evaluated, "value": f.value,
                          "message": f.message,
                          "frames": f.frames} for f in result.run_findings],
    })
