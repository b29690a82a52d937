"""The shipped rules, the validator behind `frontdiag rules check`, overrides and selection."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from test_verdicts_support import frames

from frontdiag.cli import main
from frontdiag.conditions import CONDITIONS
from frontdiag.errors import ConfigError, RuleError
from frontdiag.verdicts import (
    CHECKS,
    default_rules_dir,
    evaluate,
    load_ruleset,
    validate_dir,
)
from frontdiag.verdicts.model import RuleText

RULE = '''
[[rule]]
id = "FD-TST-001"
title = "a test rule"
condition = "{condition}"
severity = "warn"
severity_reason = "because"
sensor = "camera"

[[rule.when]]
metric = "{metric}"
op = "{op}"
value = 0.5
reason = "a reason"

[rule.text]
symptom = "s"
reveals = "r"
healthy = "h"
broken = "b"
distinguish = "d"
fix = "f"
wrong_fix = "w"
source = "our notes"
'''


def _dir(tmp_path: Path, **kw: str) -> Path:
    d = tmp_path / "rules"
    d.mkdir(exist_ok=True)
    spec = {"condition": "feature_clustering", "metric": "entropy_norm", "op": "<", **kw}
    (d / "test.toml").write_text(RULE.format(**spec))
    return d


def test_shipped_rules_are_valid() -> None:
    assert validate_dir() == []


def test_every_condition_has_a_rule() -> None:
    rs = load_ruleset()
    assert {r.condition for r in rs.rules} == set(CONDITIONS)


def test_every_shipped_rule_has_all_text_and_reasons() -> None:
    rs = load_ruleset()
    for r in rs.rules:
        for name in RuleText.model_fields:
            assert len(getattr(r.text, name).strip()) > 3, (r.id, name)
        assert r.severity_reason.strip()
        assert all(c.reason.strip() for c in r.when)
        assert all(p.reason.strip() for p in r.params.values())
        if r.persistence:
            assert r.persistence.reason.strip()


def test_every_named_check_is_used_by_a_shipped_rule() -> None:
    used = {r.check for r in load_ruleset().rules}
    assert set(CHECKS) <= used


def test_default_dir_is_the_repository_rules() -> None:
    assert default_rules_dir() == Path(__file__).resolve().parents[1] / "rules"


@pytest.mark.parametrize(("kw", "needle"), [
    ({"metric": "entropy_nrom"}, "unknown metric 'entropy_nrom'"),
    ({"op": "=~"}, "unknown operator '=~'"),
    ({"condition": "lens_flare"}, "unknown condition 'lens_flare'"),
    ({"metric": "lidar_cond"}, "is a lidar metric"),
    ({"condition": "registration_degeneracy"}, "is shown by lidar rows"),
])
def test_validator_rejects_bad_rules(tmp_path, kw, needle) -> None:
    problems = validate_dir(_dir(tmp_path, **kw))
    assert any(needle in p for p in problems), problems


@pytest.mark.parametrize(("kw", "needle"), [
    ({"metric": "entropy_nrom"}, "unknown metric"),
    ({"op": "=~"}, "unknown operator"),
    ({"condition": "lens_flare"}, "unknown condition"),
])
def test_rules_check_exits_2_with_one_line_per_problem(tmp_path, capsys, kw, needle) -> None:
    d = _dir(tmp_path, **kw)
    assert main(["rules", "check", str(d)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0] and "FD-TST-001" in err[0]


def test_rules_check_passes_on_shipped_rules(capsys) -> None:
    assert main(["rules", "check"]) == 0
    assert "all valid" in capsys.readouterr().out


def test_validator_catches_structure_problems(tmp_path) -> None:
    d = tmp_path / "r"
    d.mkdir()
    text = RULE.format(condition="pure_rotation", metric="h_over_e", op="<")
    (d / "a.toml").write_text('bogus = 1\n' + text.replace('op = "<"\nvalue = 0.5',
                                                         'op = "between"\nvalue = 0.5'))
    (d / "b.toml").write_text(text.replace('check', 'x') + '\n[[rule]]\nid = "bad"\n')
    problems = validate_dir(d)
    joined = "\n".join(problems)
    assert "needs [low, high]" in joined
    assert "unknown top-level key 'bogus'" in joined
    assert "defined in both a and b" in joined
    assert "rule bad:" in joined


def test_unknown_check_and_missing_params_are_reported(tmp_path) -> None:
    d = _dir(tmp_path)
    text = (d / "test.toml").read_text().replace('sensor = "camera"', 'sensor = "camera"\n'
                                                 'check = "clustering"')
    (d / "test.toml").write_text(text)
    assert any("needs params" in p for p in validate_dir(d))
    (d / "test.toml").write_text(text.replace('"clustering"', '"astrology"'))
    assert any("unknown check 'astrology'" in p for p in validate_dir(d))


def test_load_ruleset_raises_rule_error_on_invalid_files(tmp_path) -> None:
    with pytest.raises(RuleError, match="unknown metric"):
        load_ruleset(_dir(tmp_path, metric="nope"))
    assert main(["rules", "list", "--rules", str(_dir(tmp_path, metric="nope"))]) == 2


def test_missing_rules_dir_is_a_config_error(tmp_path) -> None:
    with pytest.raises(ConfigError):
        load_ruleset(tmp_path / "absent")


# --- overrides ----------------------------------------------------------------------------------

def test_override_file_changes_a_threshold(tmp_path) -> None:
    t = frames(20, {range(5, 15): {"entropy_norm": 0.58, "pose_info_cond": 5000.0}})
    assert "FD-CLU-001" in evaluate(t, load_ruleset()).table.loc[10, "rules"]
    ov = tmp_path / "ov.toml"
    ov.write_text('[FD-CLU-001]\nthreshold.entropy_alarm = 0.55\n')
    rs = load_ruleset(overrides=ov)
    assert rs.get("FD-CLU-001").param("entropy_alarm") == 0.55
    assert list(evaluate(t, rs).table.loc[10, "rules"]) == []


def test_override_clause_threshold_severity_persistence_and_disable(tmp_path) -> None:
    ov = tmp_path / "ov.toml"
    ov.write_text('[FD-DET-001]\nthreshold.keypoint_fill = 0.15\nseverity = "warn"\n'
                  '[FD-ROT-001]\npersistence = { k = 1, n = 1 }\n'
                  '[FD-REP-001]\nenabled = false\n'
                  '[run.episodes]\nmax_gap_frames = 0\n')
    rs = load_ruleset(overrides=ov)
    det = rs.get("FD-DET-001")
    assert det.when[0].value == 0.15 and det.severity == "warn"
    assert rs.get("FD-ROT-001").persistence.k == 1
    assert "FD-REP-001" not in {r.id for r in rs.rules}
    assert rs.run.episodes.max_gap_frames == 0
    t = frames(20, {range(5, 8): {"n_keypoints": 200}})
    assert (evaluate(t, rs).table["verdict"] == "ok").all()


@pytest.mark.parametrize(("text", "needle"), [
    ('[FD-XXX-999]\nseverity = "warn"\n', "unknown rule"),
    ('[FD-CLU-001]\nthreshold.entropy = 0.5\n', "no threshold 'entropy'"),
    ('[FD-CLU-001]\ncolour = "red"\n', "unknown keys"),
    ('[FD-CLU-001]\nseverity = "fatal"\n', "severity"),
    ('[FD-PLN-001]\nthreshold.want = "sideways"\n', "must be one of"),
    ('[FD-CLU-001\n', "not valid TOML"),
    ('[run.episode_limits]\nlens_flare = { max_s = 1, reason = "x" }\n', "unknown condition"),
])
def test_bad_override_files_are_config_errors(tmp_path, text, needle) -> None:
    ov = tmp_path / "ov.toml"
    ov.write_text(text)
    with pytest.raises(ConfigError, match=needle):
        load_ruleset(overrides=ov)


# --- selection ----------------------------------------------------------------------------------

def test_select_and_ignore_by_id_prefix_condition_and_file() -> None:
    ids = lambda **kw: {r.id for r in load_ruleset(**kw).rules}  # noqa: E731
    assert ids(select=["FD-CLU"]) == {"FD-CLU-001", "FD-CLU-002", "FD-CLU-003", "FD-CLU-004"}
    assert ids(select=["pure_rotation,FD-DET-001"]) == {"FD-ROT-001", "FD-DET-001"}
    assert ids(select=["camera_geometry"]) == {"FD-PLN-001", "FD-ROT-001", "FD-RAN-001"}
    everything = ids()
    assert ids(ignore=["FD-RUN-001", "lidar"]) == everything - {"FD-RUN-001", "FD-REG-001"}


def test_unknown_selector_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match="matches no rule"):
        load_ruleset(select=["FD-NOPE"])


def test_user_rules_dir_copy_loads(tmp_path) -> None:
    d = tmp_path / "mine"
    shutil.copytree(default_rules_dir(), d)
    assert len(load_ruleset(d).rules) == len(load_ruleset().rules)
