"""Versioned identifiers of the JSON documents frontdiag prints with ``--json``.

Each document carries ``"schema": "<id>"``; the JSON Schema of every id is generated from the
pydantic models in :mod:`frontdiag.json_models` and published in ``docs/schemas/<name>.json``.
A field is only ever added within a version; renaming or removing one makes a new version.
"""

from __future__ import annotations

SCHEMA_BASE = "https://frontdiag.dev/schemas"
VERSION = 1


def schema_id(name: str) -> str:
    """``frontdiag/<name>/v<VERSION>``: the value of a document's ``schema`` field."""
    return f"frontdiag/{name}/v{VERSION}"


ANALYZE_SCHEMA = schema_id("analyze")
INFO_SCHEMA = schema_id("info")
INFO_FLEET_SCHEMA = schema_id("info-fleet")
EXPLAIN_SCHEMA = schema_id("explain")
RULES_LIST_SCHEMA = schema_id("rules-list")
RULES_EXPLAIN_SCHEMA = schema_id("rules-explain")
RULES_CHECK_SCHEMA = schema_id("rules-check")
SCENARIOS_SCHEMA = schema_id("simulate-list")
EVAL_SCHEMA = schema_id("eval")
