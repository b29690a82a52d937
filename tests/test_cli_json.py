"""--json on every command a machine reads: each document validates against its published
JSON Schema (docs/schemas/), and the published schemas are the ones the models generate."""

from __future__ import annotations

import json
from pathlib import Path

import jsonschema
import pytest
from recording_factory import write_recording

from frontdiag import json_models
from frontdiag.cli import main

SCHEMAS = Path(__file__).resolve().parents[1] / "docs" / "schemas"


def run_json(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, dict]:
    code = main(args)
    out = capsys.readouterr().out
    return code, json.loads(out)


def validate(name: str, doc: dict) -> None:
    schema = json.loads((SCHEMAS / f"{name}.json").read_text())
    jsonschema.Draft202012Validator(schema).validate(doc)
    assert doc["schema"] == f"frontdiag/{name}/v1"


def test_published_schemas_are_the_generated_ones() -> None:
    for name in json_models.DOCUMENTS:
        published = json.loads((SCHEMAS / f"{name}.json").read_text())
        assert published == json_models.json_schema(name), \
            f"docs/schemas/{name}.json is stale: python -m frontdiag.json_models docs/schemas"


@pytest.fixture(scope="module")
def result_dir(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    tmp = tmp_path_factory.mktemp("json")
    log = write_recording(tmp / "plane.mcap", "mcap", n=6, shift=4)
    out = tmp / "res"
    assert main(["analyze", str(log), "--out", str(out), "-q", "--fail-on", "never"]) == 0
    return log, out


def test_analyze_and_info_json_validate(result_dir: tuple[Path, Path],
                                        capsys: pytest.CaptureFixture[str]) -> None:
    log, _ = result_dir
    code, doc = run_json(["analyze", str(log), "--json", "--fail-on", "never"], capsys)
    assert code == 0
    validate("analyze", doc)
    assert doc["verdicts"]["gate"]["passed"] is True and doc["interrupted"] is False
    code, doc = run_json(["info", str(log), "--json"], capsys)
    validate("info", doc)


def test_explain_json_validates_and_reads_both_status_and_verdict(
        result_dir: tuple[Path, Path], capsys: pytest.CaptureFixture[str]) -> None:
    _, out = result_dir
    code, doc = run_json(["explain", str(out), "--frame", "4", "--json"], capsys)
    assert code == 0
    validate("explain", doc)
    assert doc["frame"] == 4 and doc["status_meaning"] and doc["verdict"] in ("ok", "warn", "fail")
    assert doc["frame_range"] == {"first": 0, "last": 5}


def test_explain_says_when_a_metric_is_missing_from_an_older_table(
        result_dir: tuple[Path, Path], tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    """A table written before a rule's metric existed: the clause says so and how to get it,
    in the text and in the JSON, instead of printing the value as None."""
    import shutil

    import pandas as pd

    from frontdiag.cli import main

    _, out = result_dir
    old = tmp_path / "old"
    shutil.copytree(out, old)
    table = pd.read_parquet(old / "frames.parquet")
    table.drop(columns=["lit_share"]).to_parquet(old / "frames.parquet")
    code, doc = run_json(["explain", str(old), "--frame", "4", "--json"], capsys)
    assert code == 0
    validate("explain", doc)
    clause = next(c for r in doc["rules"] if r["id"] == "FD-DET-003" for c in r["clauses"])
    assert clause["metric"] == "lit_share" and clause["in_table"] is False
    assert not clause["holds"]
    assert main(["explain", str(old), "--frame", "4"]) == 0
    assert "lit_share not in this table (written by an older frontdiag)" in \
        capsys.readouterr().out


def test_rules_and_scenarios_json_validate(capsys: pytest.CaptureFixture[str]) -> None:
    code, doc = run_json(["rules", "list", "--json"], capsys)
    validate("rules-list", doc)
    assert any(r["id"] == "FD-PLN-001" for r in doc["rules"])
    code, doc = run_json(["rules", "explain", "FD-PLN-001", "--json"], capsys)
    validate("rules-explain", doc)
    assert doc["rule"]["id"] == "FD-PLN-001" and "h_over_e" in doc["units"]
    code, doc = run_json(["rules", "check", "--json"], capsys)
    assert code == 0
    validate("rules-check", doc)
    code, doc = run_json(["simulate", "--list", "--json"], capsys)
    validate("simulate-list", doc)
    assert any(s["name"] == "healthy_loop" for s in doc["scenarios"])


def test_eval_json_validates(result_dir: tuple[Path, Path], tmp_path: Path,
                             capsys: pytest.CaptureFixture[str]) -> None:
    _, out = result_dir
    labels = tmp_path / "l.csv"
    labels.write_text("t_start_ns,t_end_ns,condition\n")
    code, doc = run_json(["eval", str(out), "--labels", str(labels), "--json"], capsys)
    assert code == 0
    validate("eval", doc)
