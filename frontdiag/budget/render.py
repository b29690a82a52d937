"""Budget reports as grids of strings, rendered to a rich table or to GitHub markdown.

Building the grid is separate from drawing it so that the terminal and the PR comment always
show the same numbers. Nothing here prints; the CLI hands the renderables to a console.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from frontdiag.budget.measured import MeasuredReport
from frontdiag.budget.model import BudgetReport, Comparison, SensorBudget, icp_iterations


@dataclass(frozen=True)
class Grid:
    title: str
    headers: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    # indices of rows after which a rule is drawn (summary rows follow the stages)
    sections: tuple[int, ...] = ()
    notes: tuple[str, ...] = field(default_factory=tuple)


def _ms(x: float) -> str:
    return f"{x:.1f}" if abs(x) >= 0.95 or x == 0 else f"{x:.2f}"


def _pct(x: float) -> str:
    return f"{100 * x:.1f}"


def _sensor_title(report: BudgetReport, sensor: SensorBudget) -> str:
    w = report.workload
    if sensor.sensor == "camera":
        what = f"camera {w.width}×{w.height} mono @ {w.rate_hz:g} Hz, {w.features} features"
    else:
        what = (f"LiDAR {w.lidar_beams}×{w.lidar_columns} @ {w.lidar_rate_hz:g} Hz, "
                f"{w.icp} ICP × {icp_iterations(w)} iters")
    return f"Budget on {report.target} — {what}"


def sensor_grid(report: BudgetReport, sensor: SensorBudget) -> Grid:
    rows = [(s.name, s.work, _ms(s.ms), _ms(s.running_ms)) for s in sensor.stages]
    summary = [
        ("Period", f"1 / {1000 / sensor.period_ms:g} Hz", _ms(sensor.period_ms), ""),
        ("Utilisation", f"{_ms(sensor.total_ms)} of {_ms(sensor.period_ms)} ms",
         f"{_pct(sensor.utilisation)} %", ""),
        ("Margin", "absorbs slow frames, page faults, the mapping thread",
         _ms(sensor.margin_ms), ""),
    ]
    return Grid(_sensor_title(report, sensor), ("Stage", "Work", "Time (ms)",
                                                 "Running total (ms)"),
                tuple(rows + summary), sections=(len(rows) - 1,))


def report_grids(report: BudgetReport) -> list[Grid]:
    grids = [sensor_grid(report, s) for s in report.sensors]
    d = report.derived
    facts = (f"pyramid ×{d['pyramid_factor']:.3f} = {d['pyramid_px'] / 1e6:.2f} Mpx per frame · "
             f"ORB descriptors {d['descriptor_mb_s']:.2f} MB/s vs raw image "
             f"{d['image_mb_s']:.1f} MB/s · RANSAC {d['ransac_iterations']:.0f} iterations")
    notes = (facts, *(f"[{i}] {n}" for i, n in enumerate(report.footnotes, 1)))
    last = grids[-1]
    grids[-1] = Grid(last.title, last.headers, last.rows, last.sections, notes)
    return grids


# stage names in a comparison, where a variant may change the method (guided vs brute, ICP kind)
SHORT_NAMES = {"pyramid": "Undistort + pyramid", "fast": "FAST detect + NMS + bucket",
               "describe": "BRIEF describe", "match": "Match + ratio + mutual",
               "ransac": "RANSAC", "pnp": "PnP + Gauss–Newton refine", "deskew": "Deskew",
               "voxel": "Voxel downsample", "kdtree": "KD-tree build", "icp": "ICP iterations"}


def _row(label: str, sensors: list[SensorBudget | None], fn: Callable[[SensorBudget], str]
         ) -> tuple[str, ...]:
    return (label, *("—" if s is None else fn(s) for s in sensors))


def _stage_ms(key: str) -> Callable[[SensorBudget], str]:
    return lambda s: _ms(s.stage(key).ms)


def _delta(base: SensorBudget | None) -> Callable[[SensorBudget], str]:
    return lambda s: "—" if base is None else f"{s.total_ms - base.total_ms:+.1f}"


def comparison_grids(cmp: Comparison) -> list[Grid]:
    if not cmp.variants:
        return report_grids(cmp.baseline)
    reports = [("baseline", cmp.baseline), *cmp.variants]
    headers = ("Stage", *(f"{label} (ms)" for label, _ in reports))
    grids = []
    for kind in ("camera", "lidar"):
        sensors = [next((s for s in r.sensors if s.sensor == kind), None) for _, r in reports]
        present = [s for s in sensors if s is not None]
        if not present:
            continue
        base = sensors[0]
        rows = [_row(SHORT_NAMES.get(st.key, st.name), sensors, _stage_ms(st.key))
                for st in present[0].stages]
        n_stages = len(rows)
        rows += [
            _row("Total (ms)", sensors, lambda s: _ms(s.total_ms)),
            _row("Δ vs baseline (ms)", sensors, _delta(base)),
            _row("Period (ms)", sensors, lambda s: _ms(s.period_ms)),
            _row("Utilisation (%)", sensors, lambda s: _pct(s.utilisation)),
            _row("Margin (ms)", sensors, lambda s: _ms(s.margin_ms)),
        ]
        if kind == "camera":
            rows.append(("RANSAC iterations",
                         *(f"{r.derived['ransac_iterations']:.0f}" for _, r in reports)))
        else:
            rows.append(("ICP iterations",
                         *(str(icp_iterations(r.workload)) if r.lidar else "—"
                           for _, r in reports)))
        title = (f"What if — {kind} budget on {cmp.baseline.target} (each column changes only "
                 "what its header says)")
        grids.append(Grid(title, headers, tuple(rows), sections=(n_stages - 1,)))
    notes = tuple(f"[{i}] {n}" for i, n in enumerate(cmp.baseline.footnotes, 1))
    last = grids[-1]
    grids[-1] = Grid(last.title, last.headers, last.rows, last.sections, notes)
    return grids


def to_rich(grid: Grid):
    """A rich Table (numbers right-aligned) followed by its notes at full terminal width."""
    from rich.console import Group
    from rich.table import Table
    from rich.text import Text

    table = Table(title=grid.title, title_justify="left")
    for i, h in enumerate(grid.headers):
        table.add_column(h, justify="right" if _numeric_column(grid, i) else "left",
                         overflow="fold")
    for i, row in enumerate(grid.rows):
        table.add_row(*(Text(c) for c in row), end_section=i in grid.sections)
    return Group(table, *(Text(n) for n in grid.notes))


def _numeric_column(grid: Grid, i: int) -> bool:
    """Right-align a column when its stage rows hold numbers (summary rows may hold words)."""
    last = max(grid.sections, default=len(grid.rows) - 1)
    cells = [r[i] for r in grid.rows[: last + 1] if len(r) > i and r[i]]
    return i > 0 and bool(cells) and all(_numeric(c) for c in cells)


def _numeric(text: str) -> bool:
    t = text.replace("%", "").replace("+", "").replace("×", "").replace(",", "").strip()
    if t in ("—", ""):
        return True
    try:
        float(t.split()[0])
    except ValueError:
        return False
    return True


def to_markdown(grid: Grid) -> str:
    def esc(s: str) -> str:
        return s.replace("|", "\\|")

    lines = [f"**{esc(grid.title)}**", "",
             "| " + " | ".join(esc(h) for h in grid.headers) + " |",
             "|" + "|".join("---:" if _numeric_column(grid, i) else "---"
                            for i in range(len(grid.headers))) + "|"]
    for i, row in enumerate(grid.rows):
        cells = [esc(c) for c in row]
        if i > max(grid.sections, default=len(grid.rows)):
            cells[0] = f"**{cells[0]}**"
        lines.append("| " + " | ".join(cells) + " |")
    if grid.notes:
        lines.append("")
        lines += [f"{esc(n)}  " for n in grid.notes]
    return "\n".join(lines) + "\n"


def measured_grids(report: MeasuredReport) -> list[Grid]:
    """One grid per sensor: recorded percentiles here, then projected onto the target."""
    grids = []
    headers = ("Stage", "Ratio", "Here p50 (ms)", "Here p99.9 (ms)", "p50 (ms)", "p99 (ms)",
               "p99.9 (ms)", "max (ms)")
    for s in report.sensors:
        rows: list[tuple[str, ...]] = [(st.label, f"×{st.ratio:.2f}", _ms(st.here.p50), _ms(st.here.p999),
                 _ms(st.target.p50), _ms(st.target.p99), _ms(st.target.p999),
                 _ms(st.target.max)) for st in (*s.stages, s.frame)]
        n_stages = len(rows)
        pad = ("",) * (len(headers) - 3)
        rows += [
            ("Period (ms)", "", _ms(s.period_ms), *pad),
            ("Utilisation at p50 (%)", "", _pct(s.frame.here.p50 / s.period_ms), "",
             _pct(s.utilisation_p50), "", "", ""),
            ("Frames over the period, here", "", str(s.misses_here), *pad),
            ("Frames over the period, on target", "", str(s.misses_target), *pad),
            ("Miss rate on target (%)", "", _pct(s.miss_rate), *pad),
            ("Longest run of consecutive misses", "", str(s.longest_miss_run), *pad),
        ]
        status = ", ".join(f"{k} {v}" for k, v in sorted(s.statuses.items()))
        unsound = any(n.startswith((f"UNRELIABLE ({s.sensor})", "UNRELIABLE (calibration)"))
                      for n in report.notes)
        title = (f"{'UNRELIABLE ESTIMATE' if unsound else 'ESTIMATE'} — {s.sensor} timings recorded here ({report.result_dir}, "
                 f"{s.frames} frames{': ' + status if status else ''}), projected onto "
                 f"{report.target}; period {s.period_source}")
        grids.append(Grid(title, headers, tuple(rows), sections=(n_stages - 2, n_stages - 1)))
    notes = (report.method, f"This machine: {report.machine}, {report.machine_note}.",
             *report.notes)
    last = grids[-1]
    grids[-1] = Grid(last.title, last.headers, last.rows, last.sections, notes)
    return grids
