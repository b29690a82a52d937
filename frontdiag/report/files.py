"""Files written next to the per-frame table: episodes.parquet and the effective rules."""

from __future__ import annotations

import json
from pathlib import Path

from frontdiag.verdicts.engine import Verdicts
from frontdiag.verdicts.loader import Ruleset

RULES_SNAPSHOT = "rules.json"
EPISODES_FILE = "episodes.parquet"


def write_episodes(out_dir: Path, result: Verdicts) -> Path:
    """Write result.episodes to OUT_DIR/episodes.parquet (worst first)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / EPISODES_FILE
    result.episodes.to_parquet(path, index=False)
    return path


def write_rules_snapshot(out_dir: Path, ruleset: Ruleset) -> Path:
    """The effective rules (after overrides and selection), so `explain` reads what was used."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / RULES_SNAPSHOT
    path.write_text(json.dumps(ruleset.to_dict(), indent=1) + "\n")
    return path
