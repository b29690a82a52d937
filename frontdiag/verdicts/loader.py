"""Load, validate, override and select rules.

`validate_dir` returns every problem of a rules directory as one line each (for
`frontdiag rules check`); `load_ruleset` raises `RuleError` on the first file with problems and
`ConfigError` for a bad override file or selector.
"""

from __future__ import annotations

import copy
import difflib
import logging
import tomllib
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from frontdiag.conditions import CONDITION_SENSORS, CONDITIONS
from frontdiag.errors import ConfigError, RuleError
from frontdiag.metrics import METRICS
from frontdiag.verdicts.checks import CHECKS
from frontdiag.verdicts.model import FRACTION_KEYS, Rule, RunConfig
from frontdiag.verdicts.operators import check_value

log = logging.getLogger(__name__)

RUN_FILE = "run.toml"
_TOP_KEYS = {"about", "rule", "run"}


def default_rules_dir() -> Path:
    """The shipped rules: the repository's rules/ next to the package (editable or source
    install), else the copy a wheel carries in frontdiag/data/rules (see setup.py)."""
    import frontdiag

    here = Path(frontdiag.__file__).resolve()
    for candidate in (here.parents[1] / "rules", here.parent / "data" / "rules"):
        if candidate.is_dir() and any(candidate.glob("*.toml")):
            return candidate
    raise ConfigError("no rules directory found next to the frontdiag package",
                      hint="pass --rules DIR (a directory of rule .toml files)")


@dataclass(frozen=True)
class Ruleset:
    rules: tuple[Rule, ...]
    run: RunConfig
    sources: tuple[str, ...] = ()
    overrides: str | None = None

    @property
    def frame_rules(self) -> tuple[Rule, ...]:
        return tuple(r for r in self.rules if r.scope == "frame")

    @property
    def run_rules(self) -> tuple[Rule, ...]:
        return tuple(r for r in self.rules if r.scope == "run")

    def get(self, rule_id: str) -> Rule:
        for r in self.rules:
            if r.id == rule_id:
                return r
        raise ConfigError(f"unknown rule {rule_id!r}{did_you_mean(rule_id, [r.id for r in self.rules])}",
                          hint="`frontdiag rules list` shows the rule IDs")

    def to_dict(self) -> dict[str, Any]:
        """The effective rules (after overrides and selection), for a result directory."""
        return {"sources": list(self.sources), "overrides": self.overrides,
                "rules": [r.model_dump(mode="json") for r in self.rules],
                "run": self.run.model_dump(mode="json")}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Ruleset:
        try:
            rules = tuple(Rule.model_validate(r) for r in data["rules"])
            run = RunConfig.model_validate(data.get("run", {}))
        except (KeyError, TypeError, ValidationError) as exc:
            raise RuleError("rules snapshot", _pydantic_line(exc)) from None
        return cls(rules, run, tuple(data.get("sources", ())), data.get("overrides"))


# --- validation ---------------------------------------------------------------------------------

def _pydantic_line(exc: Exception) -> str:
    if isinstance(exc, ValidationError):
        parts = []
        for e in exc.errors():
            loc = ".".join(str(x) for x in e["loc"])
            parts.append(f"{loc}: {e['msg']}" if loc else e["msg"])
        return "; ".join(parts)
    return str(exc)


def did_you_mean(name: str, known: Iterable[str]) -> str:
    """`; did you mean 'entropy_norm'?` for a near miss, else an empty string."""
    close = difflib.get_close_matches(name, list(known), n=1, cutoff=0.6)
    return f"; did you mean {close[0]!r}?" if close else ""


def semantic_problems(rule: Rule) -> list[str]:
    """Problems pydantic cannot see: names checked against the registries and the catalogue."""
    out: list[str] = []
    if rule.condition not in CONDITIONS:
        out.append(f"unknown condition {rule.condition!r}{did_you_mean(rule.condition, CONDITIONS)}"
                   f" (known: {', '.join(CONDITIONS)})")
    elif rule.sensor not in CONDITION_SENSORS[rule.condition]:
        out.append(f"condition {rule.condition!r} is shown by "
                   f"{'/'.join(CONDITION_SENSORS[rule.condition])} rows, not {rule.sensor}")
    for c in rule.when:
        m = METRICS.get(c.metric)
        if m is None:
            out.append(f"unknown metric {c.metric!r}{did_you_mean(c.metric, METRICS)} (see "
                       "the metric catalogue, docs/derivations.md and frontdiag/metrics.py)")
        elif m.sensor not in ("any", rule.sensor):
            out.append(f"metric {c.metric!r} is a {m.sensor} metric; this rule reads "
                       f"{rule.sensor} rows")
        problem = check_value(c.op, c.value)
        if problem:
            out.append(f"clause on {c.metric!r}: {problem}")
        if c.rules_out is not None and c.rules_out not in CONDITIONS:
            out.append(f"clause on {c.metric!r}: rules_out names unknown condition "
                       f"{c.rules_out!r}")
    if rule.check is not None:
        chk = CHECKS.get(rule.check)
        if chk is None:
            out.append(f"unknown check {rule.check!r}{did_you_mean(rule.check, CHECKS)} "
                       f"(known: {', '.join(CHECKS)})")
        else:
            if chk.scope != rule.scope:
                out.append(f"check {chk.name!r} is a {chk.scope}-scope check; the rule has "
                           f"scope {rule.scope!r}")
            if chk.sensor != rule.sensor:
                out.append(f"check {chk.name!r} reads {chk.sensor} rows, not {rule.sensor}")
            missing = sorted(set(chk.params) - set(rule.params) - chk.optional)
            if missing:
                out.append(f"check {chk.name!r} needs params {missing}")
            for name, p in rule.params.items():
                problem = chk.param_problem(name, p.value)
                if problem:
                    out.append(problem)
    elif rule.params:
        out.append("params given without a check")
    return out


def _run_problems(run: RunConfig) -> list[str]:
    out = [f"run.episode_limits: unknown condition {k!r}"
           for k in run.episode_limits if k not in CONDITIONS]
    out += [f"run.max_fraction: key {k!r} must be one of {', '.join(FRACTION_KEYS)}"
            for k in run.max_fraction if k not in FRACTION_KEYS]
    out += [f"run.baseline: unknown metric {k!r}"
            for k in run.baseline.metric_median_rel_tol if k not in METRICS]
    return out


def _parse_file(path: Path) -> tuple[list[Rule], dict[str, Any] | None, list[str]]:
    """Rules and the raw [run] table of one file, and its problems as lines."""
    try:
        with path.open("rb") as fh:
            data = tomllib.load(fh)
    except (OSError, tomllib.TOMLDecodeError) as exc:
        return [], None, [f"{path}: {exc}"]
    problems = [f"{path}: unknown top-level key {k!r} (allowed: {sorted(_TOP_KEYS)})"
                for k in data if k not in _TOP_KEYS]
    rules: list[Rule] = []
    raw_rules = data.get("rule", [])
    if not isinstance(raw_rules, list):
        return [], None, [f"{path}: `rule` must be an array of tables ([[rule]])"]
    for i, raw in enumerate(raw_rules):
        label = raw.get("id", f"#{i + 1}") if isinstance(raw, dict) else f"#{i + 1}"
        try:
            rule = Rule.model_validate({**raw, "area": path.stem})
        except (ValidationError, TypeError) as exc:
            problems.append(f"{path}: rule {label}: {_pydantic_line(exc)}")
            continue
        problems += [f"{path}: rule {rule.id}: {p}" for p in semantic_problems(rule)]
        rules.append(rule)
    run = data.get("run")
    if run is not None and path.name != RUN_FILE:
        problems.append(f"{path}: a [run] table belongs in {RUN_FILE}")
    return rules, run, problems


def _read_dir(rules_dir: Path) -> tuple[list[Rule], RunConfig, list[str], list[str]]:
    if not rules_dir.is_dir():
        raise ConfigError(f"{rules_dir}: not a directory of rule files")
    files = sorted(rules_dir.glob("*.toml"))
    if not files:
        raise ConfigError(f"{rules_dir}: no *.toml rule files")
    rules: list[Rule] = []
    problems: list[str] = []
    run_raw: dict[str, Any] = {}
    for f in files:
        found, run, p = _parse_file(f)
        rules += found
        problems += p
        if run is not None:
            run_raw = run
    seen: dict[str, str] = {}
    for r in rules:
        if r.id in seen:
            problems.append(f"{rules_dir}: rule {r.id} defined in both {seen[r.id]} and {r.area}")
        seen[r.id] = r.area
    try:
        run_cfg = RunConfig.model_validate(run_raw)
        problems += [f"{rules_dir / RUN_FILE}: {p}" for p in _run_problems(run_cfg)]
    except ValidationError as exc:
        problems.append(f"{rules_dir / RUN_FILE}: [run]: {_pydantic_line(exc)}")
        run_cfg = RunConfig()
    return rules, run_cfg, problems, [str(f) for f in files]


def validate_dir(rules_dir: Path | None = None) -> list[str]:
    """Every problem of a rules directory, one line each (empty when valid)."""
    return _read_dir(rules_dir or default_rules_dir())[2]


# --- overrides and selection --------------------------------------------------------------------

def _apply_rule_override(rule: Rule, spec: Any, where: str) -> Rule:
    if not isinstance(spec, dict):
        raise ConfigError(f"{where}: [{rule.id}] must be a table")
    data = rule.model_dump()
    allowed = {"threshold", "severity", "persistence", "enabled"}
    unknown = set(spec) - allowed
    if unknown:
        raise ConfigError(f"{where}: [{rule.id}] unknown keys {sorted(unknown)} "
                          f"(allowed: {sorted(allowed)})")
    for name, value in spec.get("threshold", {}).items():
        clause = next((c for c in data["when"] if (c["key"] or c["metric"]) == name), None)
        if clause is not None:
            clause["value"] = value
        elif name in data["params"]:
            data["params"][name]["value"] = value
        else:
            raise ConfigError(f"{where}: [{rule.id}] has no threshold {name!r} "
                              f"(known: {', '.join(rule.thresholds()) or 'none'})")
    if "severity" in spec:
        data["severity"] = spec["severity"]
    if "persistence" in spec:
        p = spec["persistence"]
        if p is False or p == {}:
            data["persistence"] = None
        elif isinstance(p, dict):
            base = data["persistence"] or {"reason": "set by the override file"}
            data["persistence"] = {**base, **p}
        else:
            raise ConfigError(f"{where}: [{rule.id}] persistence must be {{k, n}} or false")
    try:
        new = Rule.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(f"{where}: [{rule.id}] {_pydantic_line(exc)}") from None
    problems = semantic_problems(new)
    if problems:
        raise ConfigError(f"{where}: [{rule.id}] {problems[0]}")
    return new


def _merge(base: dict[str, Any], extra: dict[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(base)
    for k, v in extra.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def apply_overrides(rules: list[Rule], run: RunConfig, path: Path
                    ) -> tuple[list[Rule], RunConfig, set[str]]:
    """Apply an override file; returns the rules, run config and IDs disabled by it."""
    try:
        with path.open("rb") as fh:
            data = tomllib.load(fh)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the override file ({exc.strerror})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None
    by_id = {r.id: r for r in rules}
    disabled: set[str] = set()
    for key, spec in data.items():
        if key == "run":
            try:
                run = RunConfig.model_validate(_merge(run.model_dump(), spec))
            except ValidationError as exc:
                raise ConfigError(f"{path}: [run] {_pydantic_line(exc)}") from None
            problems = _run_problems(run)
            if problems:
                raise ConfigError(f"{path}: {problems[0]}")
            continue
        if key not in by_id:
            raise ConfigError(f"{path}: unknown rule {key!r}",
                              hint="`frontdiag rules list` shows the rule IDs")
        by_id[key] = _apply_rule_override(by_id[key], spec, str(path))
        if isinstance(spec, dict) and spec.get("enabled") is False:
            disabled.add(key)
    return [by_id[r.id] for r in rules], run, disabled


def _expand(selectors: Iterable[str] | None) -> list[str]:
    return [s.strip() for item in (selectors or []) for s in item.split(",") if s.strip()]


def _matches(rule: Rule, selector: str) -> bool:
    return (rule.id == selector or rule.id.startswith(selector.rstrip("-") + "-")
            or rule.condition == selector or rule.area == selector)


def select_rules(rules: list[Rule], select: Iterable[str] | None,
                 ignore: Iterable[str] | None) -> list[Rule]:
    """Keep rules matching any --select (ID, ID prefix, condition or file stem), minus --ignore."""
    sel, ign = _expand(select), _expand(ignore)
    for s in sel + ign:
        if not any(_matches(r, s) for r in rules):
            raise ConfigError(f"--select/--ignore {s!r} matches no rule",
                              hint="use a rule ID (FD-CLU-001), a prefix (FD-CLU), a condition "
                              "name or a rules file stem")
    kept = [r for r in rules if not sel or any(_matches(r, s) for s in sel)]
    return [r for r in kept if not any(_matches(r, s) for s in ign)]


def load_ruleset(rules_dir: Path | None = None, overrides: Path | None = None,
                 select: list[str] | None = None, ignore: list[str] | None = None,
                 extra_dirs: Iterable[Path] = ()) -> Ruleset:
    """Read a rules directory (default: the shipped rules/), apply overrides and selection.

    ``extra_dirs`` adds the rules of further directories (a team's own, under its own ID
    namespace) to those of ``rules_dir``; an ID defined twice is a problem. Run-level settings
    come from ``rules_dir``'s run.toml only (change them with an override file).
    """
    rules_dir = Path(rules_dir) if rules_dir is not None else default_rules_dir()
    rules, run, problems, files = _read_dir(rules_dir)
    seen = {r.id: str(rules_dir) for r in rules}
    for extra in extra_dirs:
        added, _run, added_problems, added_files = _read_dir(Path(extra))
        problems += added_problems
        if (Path(extra) / RUN_FILE).is_file():
            problems.append(f"{Path(extra) / RUN_FILE}: run-level settings of added rules "
                            "directories are not read; put them in an --overrides file")
        for r in added:
            if r.id in seen:
                problems.append(f"{extra}: rule {r.id} is already defined in {seen[r.id]}; give "
                                "your rules their own namespace (e.g. MY-001)")
            seen[r.id] = str(extra)
        rules += added
        files += added_files
    if problems:
        more = f" (and {len(problems) - 1} more; run `frontdiag rules check {rules_dir}`)" \
            if len(problems) > 1 else ""
        raise RuleError(rules_dir, problems[0].removeprefix(f"{rules_dir}/") + more)
    disabled: set[str] = set()
    if overrides is not None:
        rules, run, disabled = apply_overrides(rules, run, Path(overrides))
    rules = [r for r in rules if r.id not in disabled]
    rules = select_rules(rules, select, ignore)
    return Ruleset(tuple(rules), run, tuple(files), str(overrides) if overrides else None)
