"""A built wheel carries the rule files and budget targets, and the package finds them there."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    pytest.importorskip("setuptools")
    pytest.importorskip("wheel")  # both come with the dev extra
    out = tmp_path_factory.mktemp("wheel")
    # build from a copy: setuptools writes build/ and *.egg-info into the source tree
    src = tmp_path_factory.mktemp("src") / "frontdiag"
    skip = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info", "build")
    for name in ("frontdiag", "rules"):
        shutil.copytree(ROOT / name, src / name, ignore=skip)
    for name in ("pyproject.toml", "setup.py", "MANIFEST.in", "README.md"):
        shutil.copy2(ROOT / name, src / name)
    proc = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
         "-w", str(out), str(src)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    (whl,) = out.glob("frontdiag-*.whl")
    return whl


def test_wheel_ships_every_rule_file_and_target(wheel: Path) -> None:
    names = set(zipfile.ZipFile(wheel).namelist())
    shipped = {p.relative_to(ROOT / "rules").as_posix() for p in (ROOT / "rules").rglob("*.toml")}
    assert shipped, "the repository has rule files"
    missing = {s for s in shipped if f"frontdiag/data/rules/{s}" not in names}
    assert not missing
    assert "frontdiag/data/rules/targets/orin-nano.toml" in names


def test_installed_wheel_finds_its_rules_and_targets(wheel: Path, tmp_path: Path) -> None:
    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target",
                    str(target), str(wheel)], check=True, capture_output=True)
    code = ("import frontdiag, pathlib;"
            "from frontdiag.verdicts.loader import default_rules_dir, load_ruleset;"
            "from frontdiag.budget.targets import available_targets;"
            "d = default_rules_dir(); rs = load_ruleset();"
            "print(pathlib.Path(frontdiag.__file__).parent in d.parents, len(rs.rules),"
            " 'orin-nano' in available_targets())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={**os.environ, "PYTHONPATH": str(target)}, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    inside, n_rules, has_target = out.stdout.split()
    assert inside == "True" and int(n_rules) >= 10 and has_target == "True"
