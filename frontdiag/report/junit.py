"""JUnit XML: one test case per rule, failing when the rule fired at or above --fail-on.

CI systems (GitLab, Jenkins, GitHub test reporters) render each failing rule with the episodes
it found; the gate's run-level reasons (max-fraction, baseline, episode limits) form one more case.
The suite is named after the recording, so reports of several recordings stay apart.

A rule that fired below --fail-on (a warn rule under ``--fail-on fail``) did find something, so
it is not reported as a passing case: it is *skipped* with a message saying what it found and
that the gate does not count it (CI reporters list skipped cases with their message; a failure
would contradict the exit code). A run-level check that could not run (no camera rows, too few
frames) is skipped as "not evaluated". Only a rule that was evaluated and found nothing passes.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

from frontdiag.verdicts.engine import Verdicts
from frontdiag.verdicts.gate import GateResult


def _episode_lines(result: Verdicts, rule_id: str) -> list[str]:
    eps = result.episodes
    if eps.empty:
        return []
    mine = eps[eps["rules"].map(lambda rs: rule_id in list(rs))]
    return [str(s) for s in mine["summary"]]


def build_junit(result: Verdicts, gate_result: GateResult,
                suite_name: str = "frontdiag") -> ET.ElementTree:
    suite = ET.Element("testsuite", name=suite_name)
    failures = 0
    skipped = 0
    cases = 0
    for rule in result.ruleset.rules:
        cases += 1
        case = ET.SubElement(suite, "testcase", classname=f"frontdiag.{rule.area or 'rules'}",
                             name=f"{rule.id} {rule.condition}: {rule.title}")
        evaluated = True
        if rule.scope == "run":
            finding = next((f for f in result.run_findings if f.rule == rule.id), None)
            lines = [finding.message] if finding else []
            fired = bool(finding and finding.fired)
            evaluated = bool(finding and finding.evaluated)
        else:
            lines = _episode_lines(result, rule.id)
            fired = result.rule_frames(rule.id) > 0
        text = "\n".join(lines)
        if rule.id in gate_result.failed_rules:
            failures += 1
            n = result.rule_frames(rule.id)
            msg = (f"{rule.condition} [{rule.severity}] on {n} frame(s) in {len(lines)} "
                   "episode(s)" if rule.scope == "frame" else lines[0] if lines else rule.title)
            fail = ET.SubElement(case, "failure", message=msg, type=rule.severity)
            fail.text = f"{text}\n\nfix: {rule.text.fix}\nwrong fix: {rule.text.wrong_fix}"
        elif fired:
            skipped += 1
            n = result.rule_frames(rule.id)
            found = f"on {n} frame(s)" if rule.scope == "frame" else (lines[0] if lines else "")
            ET.SubElement(case, "skipped", message=f"{rule.condition} [{rule.severity}] fired "
                          f"{found}; below --fail-on {gate_result.fail_on}, not gated")
            ET.SubElement(case, "system-out").text = text
        elif not evaluated:
            skipped += 1
            ET.SubElement(case, "skipped", message=f"not evaluated: {text or 'no finding'}")
        elif lines:
            ET.SubElement(case, "system-out").text = text
    rule_reasons = {f"{rid} " for rid in gate_result.failed_rules}
    other = [r for r in gate_result.reasons
             if not any(r.startswith(p) for p in rule_reasons)]
    cases += 1
    gate_case = ET.SubElement(suite, "testcase", classname="frontdiag.gate",
                              name="run-level gates (max-fraction, episode limits, baseline)")
    if other:
        failures += 1
        fail = ET.SubElement(gate_case, "failure", message=other[0], type="gate")
        fail.text = "\n".join(other)
    suite.set("tests", str(cases))
    suite.set("failures", str(failures))
    suite.set("errors", "0")
    suite.set("skipped", str(skipped))
    root = ET.Element("testsuites", name=suite_name, tests=str(cases), failures=str(failures),
                      errors="0", skipped=str(skipped))
    root.append(suite)
    return ET.ElementTree(root)


def write_junit(path: Path, result: Verdicts, gate_result: GateResult,
                suite: str = "frontdiag") -> Path:
    """Write the JUnit XML report to `path`; ``suite`` names the test suite (the recording)."""
    return _write(path, build_junit(result, gate_result, suite))


def _write(path: Path, tree: ET.ElementTree) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ET.indent(tree)
    tree.write(path, encoding="utf-8", xml_declaration=True)
    return path


def build_fleet_junit(out_dir: Path, rows: list[dict], fail_on: str) -> ET.ElementTree:
    """One test suite per recording of a fleet run (named after its result folder), each as
    :func:`build_junit` makes it from the recording's own result; a recording that could not
    be analysed is a suite with one ``error`` case carrying the reason."""
    from frontdiag.report.html import load_run
    from frontdiag.verdicts.gate import gate

    root = ET.Element("testsuites", name="frontdiag fleet")
    totals = {"tests": 0, "failures": 0, "errors": 0, "skipped": 0}
    for row in rows:
        name = str(row["recording"])
        folder = Path(out_dir) / name
        if row.get("status") == "error" or not (folder / "frames.parquet").is_file():
            suite = ET.SubElement(root, "testsuite", name=name, tests="1", failures="0",
                                  errors="1", skipped="0")
            case = ET.SubElement(suite, "testcase", classname="frontdiag.analysis",
                                 name=f"analyse {row.get('path', name)}")
            ET.SubElement(case, "error", message=str(row.get("error") or "not analysed"),
                          type="analysis")
            totals["tests"] += 1
            totals["errors"] += 1
            continue
        run = load_run(folder)
        one = build_junit(run.verdicts, gate(run.verdicts, fail_on=fail_on),  # type: ignore[arg-type]
                          suite_name=name).getroot()
        assert one is not None
        for suite in one:
            root.append(suite)
            for k in totals:
                totals[k] += int(suite.get(k, "0"))
    for k, v in totals.items():
        root.set(k, str(v))
    return ET.ElementTree(root)


def write_fleet_junit(path: Path, out_dir: Path, rows: list[dict], fail_on: str) -> Path:
    """Write the fleet's JUnit XML (:func:`build_fleet_junit`) to ``path``."""
    return _write(path, build_fleet_junit(out_dir, rows, fail_on))
