"""Measured mode: per-stage timings recorded by ``frontdiag analyze`` on this machine, summarised
as tail percentiles and projected onto a target.

Projection method (an estimate, stated in every report): each recorded stage is scaled by
``model(target) / model(this machine)``, where ``model`` is the budget model's time for the model
stages that recorded stage contains, on the recording's workload. The ratio therefore weighs each
coefficient by how much of that stage it explains. It assumes the stage scales like the
microbenchmarked operations, and it cannot see caches, memory bandwidth, thermal throttling or
other processes on the target.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from frontdiag.budget import model
from frontdiag.budget.targets import Target
from frontdiag.errors import ConfigError, RecordingError
from frontdiag.timing import median_rate_hz

# recorded column -> (label, model stages whose time ratio projects it)
CAMERA_COLUMNS: dict[str, tuple[str, tuple[str, ...]]] = {
    "ms_decode": ("Decode", ("pyramid",)),
    "ms_detect": ("Detect + describe", ("pyramid", "fast", "describe")),
    "ms_match": ("Match", ("match",)),
    "ms_geometry": ("Geometry (RANSAC + pose)", ("ransac", "pnp")),
    "ms_photometric": ("Photometric checks", ("pyramid",)),
}
LIDAR_COLUMNS: dict[str, tuple[str, tuple[str, ...]]] = {
    "ms_lidar_preprocess": ("Preprocess (deskew + voxel)", ("deskew", "voxel")),
    "ms_lidar_register": ("Register (KD-tree + ICP)", ("kdtree", "icp")),
}
SENSOR_COLUMNS = {"camera": CAMERA_COLUMNS, "lidar": LIDAR_COLUMNS}

METHOD = ("Projection: each recorded stage × model(target) / model(this machine) for the model "
          "stages it contains, on this recording's workload. An estimate: it assumes the stage "
          "scales like the microbenchmarked operations and cannot see caches, memory bandwidth, "
          "thermal limits or other load on the target.")


@dataclass(frozen=True)
class Percentiles:
    p50: float
    p99: float
    p999: float
    max: float

    @classmethod
    def of(cls, values: np.ndarray) -> Percentiles:
        if values.size == 0:
            return cls(float("nan"), float("nan"), float("nan"), float("nan"))
        p = np.percentile(values, [50, 99, 99.9])
        return cls(float(p[0]), float(p[1]), float(p[2]), float(values.max()))


@dataclass(frozen=True)
class StageStats:
    column: str
    label: str
    ratio: float  # target / this machine
    here: Percentiles
    target: Percentiles


@dataclass(frozen=True)
class SensorMeasured:
    sensor: str
    frames: int
    statuses: dict[str, int]
    period_ms: float
    period_source: str
    stages: tuple[StageStats, ...]
    frame: StageStats  # per-frame total
    misses_here: int
    misses_target: int
    longest_miss_run: int
    longest_miss_run_start_ns: int | None

    @property
    def utilisation_p50(self) -> float:
        return self.frame.target.p50 / self.period_ms

    @property
    def cascade(self) -> bool:
        """The projected tail crosses the period: dropped frames feed on each other."""
        return self.frame.target.p999 > self.period_ms

    @property
    def miss_rate(self) -> float:
        return self.misses_target / self.frames if self.frames else 0.0


@dataclass(frozen=True)
class MeasuredReport:
    result_dir: str
    target: str
    machine: str
    machine_note: str
    method: str
    sensors: tuple[SensorMeasured, ...]
    notes: tuple[str, ...]

    def to_dict(self) -> dict[str, Any]:
        def sensor(s: SensorMeasured) -> dict[str, Any]:
            d = dataclasses.asdict(s)
            d.update(utilisation_p50=s.utilisation_p50, cascade=s.cascade,
                     miss_rate=s.miss_rate)
            return d

        return {"mode": "measured", "result_dir": self.result_dir, "target": self.target,
                "machine": self.machine, "machine_note": self.machine_note,
                "method": self.method, "estimate": True,
                "sensors": [sensor(s) for s in self.sensors], "notes": list(self.notes)}


def read_frames(result_dir: Path) -> Any:
    """``frames.parquet`` (or ``frames.csv``) of an analyze result directory, as a DataFrame."""
    from frontdiag.output import read_table

    result_dir = Path(result_dir)
    if not result_dir.is_dir():
        raise RecordingError(result_dir, "not a result directory (expected the --out directory "
                             "of frontdiag analyze)")
    df = read_table(result_dir)
    missing = {"sensor", "ms_total"} - set(df.columns)
    if missing:
        raise RecordingError(result_dir, "missing column(s) " + ", ".join(sorted(missing)))
    return df


def read_manifest(result_dir: Path) -> dict[str, Any]:
    from frontdiag.output import read_manifest as _read

    return _read(Path(result_dir))


def _flatten(d: Any, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    if isinstance(d, dict):
        for k, v in d.items():
            out.update(_flatten(v, f"{prefix}{k}.".lower()))
    elif isinstance(d, list):
        for i, v in enumerate(d):
            out.update(_flatten(v, f"{prefix}{i}."))
    else:
        out[prefix[:-1]] = d
    return out


def manifest_number(manifest: dict[str, Any], sensor: str, names: tuple[str, ...]
                    ) -> float | None:
    """First positive number under a key path mentioning ``sensor`` whose last part is in
    ``names`` (tolerant of how the manifest nests camera and LiDAR information)."""
    prefixed = {f"{sensor}_{n}" for n in names}
    for path, value in _flatten(manifest).items():
        *parents, last = path.split(".")
        hit = (last in names and any(sensor in p for p in parents)) or last in prefixed
        if hit and isinstance(value, int | float) and not isinstance(value, bool) and value > 0:
            return float(value)
    return None


RATE_KEYS = ("rate_hz", "hz", "fps", "frame_rate_hz", "rate")


def _period(rows: Any, manifest: dict[str, Any], sensor: str, explicit_hz: float | None,
            default_hz: float) -> tuple[float, str]:
    if explicit_hz:
        return 1000.0 / explicit_hz, f"{explicit_hz:g} Hz from the command line"
    hz = manifest_number(manifest, sensor, RATE_KEYS)
    if hz:
        return 1000.0 / hz, f"{hz:g} Hz from manifest.json"
    if "t_ns" in rows and len(rows) >= 3:
        hz = median_rate_hz(rows["t_ns"].to_numpy(dtype=np.float64))
        if hz == hz:
            return 1000.0 / hz, f"{hz:.3g} Hz from the median frame interval"
    return 1000.0 / default_hz, f"{default_hz:g} Hz default (no rate in the result directory)"


def longest_run(flags: np.ndarray) -> tuple[int, int | None]:
    """Length and start index of the longest run of True."""
    best, start, run, run_start = 0, None, 0, 0
    for i, v in enumerate(flags):
        if v:
            if run == 0:
                run_start = i
            run += 1
            if run > best:
                best, start = run, run_start
        else:
            run = 0
    return best, start


def stage_ratios(workload: model.Workload, target: Target, machine: Target
                 ) -> dict[str, float]:
    """model(target) / model(machine) for each recorded column, and ``ms_total`` per sensor."""
    cam_t, cam_m = model.camera_stage_ms(workload, target), model.camera_stage_ms(workload, machine)
    lid_w = workload if workload.lidar_beams else dataclasses.replace(workload, lidar_beams=128)
    lid_t = {s.key: s.ms for s in model.lidar_budget(lid_w, target).stages}  # type: ignore[union-attr]
    lid_m = {s.key: s.ms for s in model.lidar_budget(lid_w, machine).stages}  # type: ignore[union-attr]
    out: dict[str, float] = {}
    for columns, t_ms, m_ms, total_key in ((CAMERA_COLUMNS, cam_t, cam_m, "camera"),
                                           (LIDAR_COLUMNS, lid_t, lid_m, "lidar")):
        for column, (_, keys) in columns.items():
            out[column] = sum(t_ms[k] for k in keys) / sum(m_ms[k] for k in keys)
        out[f"{total_key}:ms_total"] = sum(t_ms.values()) / sum(m_ms.values())
    return out


def _numeric(rows: Any, column: str) -> np.ndarray:
    import pandas as pd

    return pd.to_numeric(rows[column], errors="coerce").to_numpy(dtype=float)


def summarise_sensor(rows: Any, sensor: str, ratios: dict[str, float], period_ms: float,
                     period_source: str) -> SensorMeasured:
    if "t_ns" in rows:
        rows = rows.sort_values("t_ns", kind="stable")
    total_here = _numeric(rows, "ms_total")
    keep = np.isfinite(total_here)
    rows, total_here = rows[keep], total_here[keep]
    stages, projected_parts = [], np.zeros(len(rows))
    for column, (label, _) in SENSOR_COLUMNS[sensor].items():
        if column not in rows:
            continue
        here = np.nan_to_num(_numeric(rows, column), nan=0.0)
        ratio = ratios[column]
        stages.append(StageStats(column, label, ratio, Percentiles.of(here),
                                 Percentiles.of(here * ratio)))
        projected_parts += here * ratio
    accounted = sum(np.nan_to_num(_numeric(rows, s.column), nan=0.0) for s in stages)
    rest = np.clip(total_here - accounted, 0.0, None) if stages else total_here
    total_ratio = ratios[f"{sensor}:ms_total"]
    total_target = projected_parts + rest * total_ratio
    frame_ratio = float(total_target.sum() / total_here.sum()) if total_here.sum() > 0 else 1.0
    frame = StageStats("ms_total", "Frame total", frame_ratio, Percentiles.of(total_here),
                       Percentiles.of(total_target))
    miss = total_target > period_ms
    run, start = longest_run(miss)
    start_ns = (int(rows["t_ns"].iloc[start]) if start is not None and "t_ns" in rows
                else None)
    statuses = ({str(k): int(v) for k, v in rows["status"].value_counts().items()}
                if "status" in rows else {})
    return SensorMeasured(sensor, len(rows), statuses, period_ms, period_source, tuple(stages),
                          frame, int((total_here > period_ms).sum()), int(miss.sum()), run,
                          start_ns)


def measured_report(result_dir: Path, workload: model.Workload, target: Target,
                    machine: Target, machine_note: str, camera_hz: float | None = None,
                    lidar_hz: float | None = None, matching: str | None = None
                    ) -> MeasuredReport:
    """Summarise and project ``result_dir``; ``*_hz`` and ``matching`` override what the
    result directory says (matching defaults to brute force, frame-to-frame)."""
    df = read_frames(result_dir)
    manifest = read_manifest(result_dir)
    flat = _flatten(manifest)
    if matching is None:
        recorded = next((v for k, v in flat.items() if k.split(".")[-1] == "matching"
                         and v in model.MATCHING), None)
        matching = recorded or "brute"
    workload = dataclasses.replace(workload, matching=matching).validate()
    width = (manifest_number(manifest, "camera", ("width",))
             or manifest_number(manifest, "intrinsics", ("width",)))
    height = (manifest_number(manifest, "camera", ("height",))
              or manifest_number(manifest, "intrinsics", ("height",)))
    if width and height:
        workload = dataclasses.replace(workload, width=int(width), height=int(height))
    ratios = stage_ratios(workload, target, machine)
    sensors = []
    for sensor, default_hz in (("camera", workload.rate_hz), ("lidar", workload.lidar_rate_hz)):
        rows = df[df["sensor"].astype(str) == sensor]
        if rows.empty:
            continue
        explicit = camera_hz if sensor == "camera" else lidar_hz
        period, source = _period(rows, manifest, sensor, explicit, default_hz)
        summary = summarise_sensor(rows, sensor, ratios, period, source)
        if summary.frames:
            sensors.append(summary)
    if not sensors:
        raise RecordingError(Path(result_dir), "no camera or lidar rows with timings")
    notes = []
    recorded_on = next((v for k, v in flat.items()
                        if k.split(".")[-1] == "hostname" and isinstance(v, str)), None)
    this_host = machine.machine.get("hostname")
    if recorded_on and this_host and recorded_on != this_host:
        notes.append(f"The timings were recorded on {recorded_on}, the machine coefficients are "
                     f"from {this_host}: the projection assumes they are the same computer.")
    if machine.provenance != "calibrated":
        notes.append(f"The machine file {machine.name!r} was not calibrated on this machine.")
    for s in sensors:
        if s.cascade:
            notes.append(
                f"{s.sensor}: the projected p99.9 ({s.frame.target.p999:.1f} ms) crosses the "
                f"{s.period_ms:.1f} ms period. A missed deadline drops a frame, doubles the "
                "baseline and quadruples the guided-matching candidates, so the next frame is "
                f"slower too: misses come in runs (longest here: {s.longest_miss_run}).")
    method = METHOD
    if any(s.sensor == "camera" for s in sensors):
        method += f" Matching projected as {matching} (--matching to change)."
    notes += disagreement_notes(sensors, target, machine)
    return MeasuredReport(str(result_dir), target.name, machine.name, machine_note, method,
                          tuple(sensors), tuple(notes))


NOISY = 2.0
"""A calibration whose repeats of one timing spread wider than this (p90/p10) measured the
machine's load more than the machine."""
DISAGREE = 5.0
"""Stage ratios spreading wider than this factor within one sensor (real CPUs of one class
differ per operation by 2-3x) mean the target's
coefficients and this machine's do not describe the same kind of work."""


def disagreement_notes(sensors: list[SensorMeasured], target: Target, machine: Target
                       ) -> list[str]:
    """Say when the projection's inputs disagree, instead of presenting it as sound."""
    from frontdiag.budget.targets import PROVENANCE_WORDS

    out = []
    noisy = {c.name: c.spread for c in machine.coefficients.values()
             if c.spread is not None and c.spread > NOISY}
    if noisy:
        out.append("UNRELIABLE (calibration): this machine's timings varied by more than "
                   f"×{NOISY:g} between repeats (p90/p10) for "
                   + ", ".join(f"{k} ×{v:.2g}" for k, v in sorted(noisy.items()))
                   + "; the machine was busy while it calibrated. Rerun `frontdiag budget "
                   "--from DIR --recalibrate` on an idle machine.")
    for s in sensors:
        ratios = [st.ratio for st in s.stages if st.ratio > 0]
        if len(ratios) >= 2 and max(ratios) / min(ratios) > DISAGREE:
            out.append(f"UNRELIABLE ({s.sensor}): the per-stage ratios range from ×{min(ratios):.2f} "
                       f"to ×{max(ratios):.2f}, a factor {max(ratios) / min(ratios):.0f}; one "
                       "computer does not differ from another this unevenly, so the target's "
                       "coefficients and this machine's calibration disagree. Read the numbers "
                       "as a rough order, not a prediction.")
        if s.frame.ratio < 1.0:
            out.append(f"The projection makes {target.name} {1 / s.frame.ratio:.1f}× faster than "
                       f"this machine on {s.sensor} frames. {target.name}'s coefficients are "
                       f"{PROVENANCE_WORDS.get(target.provenance, target.provenance)}; this "
                       f"machine's are {PROVENANCE_WORDS.get(machine.provenance, machine.provenance)}"
                       " (a loaded or virtual machine calibrates slow). Check both before "
                       "trusting the projection.")
    return out


def check_gates(report: MeasuredReport, max_util: float | None,
                max_p999_ms: float | None) -> list[str]:
    """Messages for each gate the projected timings exceed (empty: within budget)."""
    if (max_util is not None and max_util <= 0) or (max_p999_ms is not None
                                                     and max_p999_ms <= 0):
        raise ConfigError("gates must be positive")
    out = []
    for s in report.sensors:
        if max_util is not None and s.utilisation_p50 > max_util:
            out.append(f"{s.sensor}: projected p50 utilisation {100 * s.utilisation_p50:.1f} % "
                       f"exceeds --max-util {100 * max_util:.1f} %")
        if max_p999_ms is not None and s.frame.target.p999 > max_p999_ms:
            out.append(f"{s.sensor}: projected p99.9 frame time {s.frame.target.p999:.1f} ms "
                       f"exceeds --max-p999-ms {max_p999_ms:g}")
    return out
