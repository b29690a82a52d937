"""Targets are data: a machine's per-operation coefficients and where each one came from.

A target file is TOML (see ``rules/targets/orin-nano.toml``)::

    [target]
    name = "orin-nano"
    description = "..."
    provenance = "reference"       # reference | calibrated

    [coefficients.fast_ns_per_px]
    value = 3.0
    how = "given"                  # given | derived | measured
    source = "where the number comes from"

Nothing here invents a coefficient: a stage whose coefficient a target lacks is refused with a
message that says how to obtain it (calibrate on the machine).
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from frontdiag.errors import ConfigError

#: Every coefficient a target may hold: name -> (unit, what one unit of work is).
COEFFICIENTS: dict[str, tuple[str, str]] = {
    "resample_ns_per_px": ("ns/px", "undistort + pyramid resampling, per pyramid pixel"),
    "fast_ns_per_px": ("ns/px", "FAST segment test + NMS, per pyramid pixel"),
    "describe_us_per_kp": ("µs/kp", "orientation + 256-test BRIEF, per keypoint"),
    "match_us_per_query": ("µs/query", "per-query matching overhead (window, ratio, mutual)"),
    "hamming_ns_per_comparison": ("ns", "one 256-bit Hamming distance"),
    "solve_5pt_us": ("µs", "one 5-point essential-matrix minimal solve"),
    "solve_8pt_us": ("µs", "one 8-point linear fundamental-matrix solve"),
    "sampson_ns_per_residual": ("ns", "one Sampson residual"),
    "pnp_ns_per_residual": ("ns", "PnP stage cost per refinement residual (points × iters)"),
    "deskew_ns_per_point": ("ns/pt", "LiDAR motion compensation, per raw point"),
    "voxel_ns_per_point": ("ns/pt", "voxel downsampling, per raw point"),
    "kdtree_ns_per_nlogn": ("ns", "KD-tree build, per n·log2(n) of the local map"),
    "nn_ns_per_query_log": ("ns", "nearest-neighbour query, per query per log2(map points)"),
    "icp_solve_ns_per_point": ("ns/pt", "ICP solve + apply per iteration, per source point"),
}

HOW = ("given", "derived", "measured")


@dataclass(frozen=True)
class Coefficient:
    name: str
    value: float
    how: str  # given | derived | measured
    source: str
    spread: float | None = None
    """Measured coefficients: p90 / p10 of the timings behind the value (1.0 = every repeat
    took the same time); how far one calibration can be trusted."""

    @property
    def unit(self) -> str:
        return COEFFICIENTS[self.name][0]


PROVENANCE_ALIASES = {"published": "reference"}
"""Target files written by earlier versions call reference figures "published"."""

PROVENANCE_WORDS = {
    "reference": "reference estimates of per-unit costs for that hardware (engineering "
                 "rules of thumb, not measured by frontdiag: `frontdiag budget --calibrate` "
                 "times your own machine)",
    "calibrated": "timed by `frontdiag budget --calibrate` on the machine the file names",
}
HOW_WORDS = {
    "given": "stated per unit by the source",
    "derived": "a stated stage time divided by the work it was stated for",
    "measured": "timed on the machine",
}


@dataclass(frozen=True)
class Target:
    name: str
    description: str
    provenance: str  # reference (estimates, not measured here) | calibrated
    coefficients: dict[str, Coefficient]
    path: Path | None = None
    machine: dict[str, str] = field(default_factory=dict)

    def has(self, name: str) -> bool:
        return name in self.coefficients

    def get(self, name: str) -> float:
        """The coefficient's value; a missing one is a ConfigError naming the way to get it."""
        try:
            return self.coefficients[name].value
        except KeyError:
            raise ConfigError(
                f"target {self.name!r} has no {name} ({COEFFICIENTS[name][1]})",
                hint="nobody measured it for this hardware; run `frontdiag budget --calibrate "
                     "-o FILE` on that machine and pass --target FILE",
            ) from None


def targets_dir() -> Path:
    """The shipped target files: ``targets/`` of the shipped rules directory."""
    from frontdiag.verdicts.loader import default_rules_dir

    try:
        return default_rules_dir() / "targets"
    except ConfigError:
        return Path(__file__).resolve().parents[2] / "rules" / "targets"


def available_targets(directory: Path | None = None) -> list[str]:
    d = directory or targets_dir()
    return sorted(p.stem for p in d.glob("*.toml")) if d.is_dir() else []


def resolve_target(name_or_path: str, directory: Path | None = None) -> Path:
    """A shipped target name (``orin-nano``) or a path to a target file."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists():
        if not p.is_file():
            raise ConfigError(f"{p}: target file not found")
        return p
    d = directory or targets_dir()
    candidate = d / f"{name_or_path}.toml"
    if candidate.is_file():
        return candidate
    names = ", ".join(available_targets(d)) or "none"
    raise ConfigError(f"unknown target {name_or_path!r}; available targets: {names}",
                      hint="or pass the path of a target file written by --calibrate")


def load_target(name_or_path: str, directory: Path | None = None) -> Target:
    path = resolve_target(name_or_path, directory)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read target file: {exc}") from exc
    return parse_target(data, path)


def parse_target(data: dict, path: Path | None = None) -> Target:
    where = str(path) if path else "target"
    head = data.get("target")
    if not isinstance(head, dict) or not isinstance(head.get("name"), str):
        raise ConfigError(f"{where}: needs a [target] table with a name")
    raw = data.get("coefficients")
    if not isinstance(raw, dict) or not raw:
        raise ConfigError(f"{where}: needs a [coefficients] table")
    coeffs: dict[str, Coefficient] = {}
    for key, entry in raw.items():
        if key not in COEFFICIENTS:
            raise ConfigError(f"{where}: unknown coefficient {key!r}; known: "
                              + ", ".join(COEFFICIENTS))
        if not isinstance(entry, dict):
            raise ConfigError(f"{where}: coefficients.{key} must be a table with value and source")
        value, source, how = entry.get("value"), entry.get("source"), entry.get("how", "given")
        if isinstance(value, bool) or not isinstance(value, int | float) or not value > 0:
            raise ConfigError(f"{where}: coefficients.{key}.value must be a positive number")
        if not isinstance(source, str) or not source.strip():
            raise ConfigError(f"{where}: coefficients.{key} needs a source saying where it "
                              "came from")
        if how not in HOW:
            raise ConfigError(f"{where}: coefficients.{key}.how must be one of {', '.join(HOW)}")
        spread = entry.get("spread")
        if spread is not None and (isinstance(spread, bool) or not isinstance(spread, int | float)
                                   or not spread >= 1):
            raise ConfigError(f"{where}: coefficients.{key}.spread must be a number >= 1")
        coeffs[key] = Coefficient(key, float(value), how, source,
                                  None if spread is None else float(spread))
    machine = data.get("machine", {})
    return Target(
        name=head["name"],
        description=str(head.get("description", "")),
        provenance=PROVENANCE_ALIASES.get(str(head.get("provenance", "")),
                                          str(head.get("provenance", ""))),
        coefficients=coeffs,
        path=path,
        machine={str(k): str(v) for k, v in machine.items()} if isinstance(machine, dict) else {},
    )


def _toml_str(s: str) -> str:
    # A JSON string literal is a valid TOML basic string (same escapes).
    return json.dumps(s, ensure_ascii=False)


def target_to_toml(target: Target, header: str = "") -> str:
    """Serialise a target so that :func:`parse_target` reads it back unchanged."""
    lines = [f"# {line}" if line else "#" for line in header.splitlines()]
    if lines:
        lines.append("")
    lines += ["[target]", f"name = {_toml_str(target.name)}",
              f"description = {_toml_str(target.description)}",
              f"provenance = {_toml_str(target.provenance)}", ""]
    if target.machine:
        lines.append("[machine]")
        lines += [f"{k} = {_toml_str(v)}" for k, v in target.machine.items()]
        lines.append("")
    for name in COEFFICIENTS:
        c = target.coefficients.get(name)
        if c is None:
            continue
        lines += [f"[coefficients.{name}]", f"value = {c.value:.6g}",
                  f"how = {_toml_str(c.how)}", f"source = {_toml_str(c.source)}"]
        if c.spread is not None:
            lines.append(f"spread = {c.spread:.3g}")
        lines.append("")
    return "\n".join(lines)
