"""The rule engine: the reference failure taxonomy as data, evaluated over the per-frame table.

    ruleset = load_ruleset()                       # rules/*.toml, overrides, --select/--ignore
    result = evaluate(table, ruleset)              # per-row verdicts, episodes, run findings
    g = gate(result, fail_on="fail")               # exit code 0 / 1 and the reasons

Rules live in `rules/` (one TOML file per area); operators and named checks are closed
registries (`OPERATORS`, `CHECKS`). Nothing from a rules file is ever executed.
"""

from __future__ import annotations

from frontdiag.verdicts.checks import CHECKS
from frontdiag.verdicts.engine import RunFinding, Verdicts, evaluate
from frontdiag.verdicts.gate import GateResult, gate, parse_max_fraction
from frontdiag.verdicts.loader import Ruleset, default_rules_dir, load_ruleset, validate_dir
from frontdiag.verdicts.operators import OPERATORS

__all__ = [
    "CHECKS",
    "OPERATORS",
    "GateResult",
    "Ruleset",
    "RunFinding",
    "Verdicts",
    "default_rules_dir",
    "evaluate",
    "gate",
    "load_ruleset",
    "parse_max_fraction",
    "validate_dir",
]
