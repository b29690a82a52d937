"""`frontdiag budget`: the frontend's latency budget on a target machine, derived or measured."""

from __future__ import annotations

from pathlib import Path

import typer

HELP = """The frontend's latency budget on a target computer, stage by stage.

Derived (default): each stage's work (pyramid pixels, keypoints, candidates,
RANSAC iterations) times the target's per-unit coefficients, then the
period, utilisation and margin.

Measured (--from RESULT_DIR): the per-stage timings `frontdiag analyze
--out` recorded on this machine, as p50/p99/p99.9/max, projected onto the
target by the ratio of the target's coefficients to this machine's (an
estimate, and the output says so), with the frames that would miss the
deadline.

Targets are TOML files in rules/targets (or a path to one); --calibrate
writes one for this machine. Gates: --max-util and --max-p999-ms exit 1 when
over, 2 on bad input.

Examples:

  frontdiag budget --target orin-nano

  frontdiag budget --what-if matching=brute --what-if inlier-ratio=0.7

  frontdiag budget --lidar 128x1800@10 --icp point-to-point

  frontdiag budget --calibrate -o rules/targets/my-robot.toml

  frontdiag budget results/ --target orin-nano --max-p999-ms 33    # measured timings (= --from)

  frontdiag budget --max-util 0.6 --markdown
"""


def register(app: typer.Typer) -> None:
    """Add the command to the app."""

    @app.command("budget", help=HELP, no_args_is_help=False)
    def budget(
        result_dir: Path | None = typer.Argument(
            None, metavar="[RESULT_DIR]", show_default=False,
            help="Result directory of `frontdiag analyze --out` (the same as --from): its "
            "measured timings, projected onto the target."),
        target: str = typer.Option("orin-nano", "--target", "-t",
                                   help="Target name in rules/targets, or a target .toml file."),
        camera: str | None = typer.Option(None, "--camera", help="Camera as WxH@HZ "
                                          "(default 1280x720@30; with --from: the recording's)."),
        features: int = typer.Option(1000, "--features", help="Keypoints per frame."),
        levels: int = typer.Option(8, "--levels", help="Pyramid levels."),
        scale: float = typer.Option(1.2, "--scale", help="Pyramid scale factor."),
        matching: str | None = typer.Option(
            None, "--matching", metavar="[guided|brute]", help="guided (window around the prediction) or brute "
            "(default guided; with --from: the recording's, else brute)."),
        search_radius: float = typer.Option(25.0, "--search-radius",
                                            help="Guided search window radius (px)."),
        correspondences: int = typer.Option(400, "--correspondences",
                                            help="Correspondences M scored per RANSAC iteration."),
        inlier_ratio: float = typer.Option(0.5, "--inlier-ratio", help="Inlier ratio w."),
        confidence: float = typer.Option(0.999, "--confidence", help="RANSAC confidence p."),
        solver: str = typer.Option("5pt", "--solver", metavar="[5pt|8pt]", help="Minimal solver: 5pt or 8pt."),
        pnp_points: int = typer.Option(200, "--pnp-points", help="Map points in PnP."),
        pnp_iters: int = typer.Option(4, "--pnp-iters", help="Gauss–Newton iterations."),
        lidar: str | None = typer.Option(None, "--lidar",
                                         help="Add the LiDAR budget: BEAMSxCOLUMNS@HZ."),
        icp: str = typer.Option("point-to-plane", "--icp", metavar="[point-to-point|point-to-plane]",
                                help="point-to-point (40 iters) or point-to-plane (8 iters)."),
        icp_iters: int | None = typer.Option(None, "--icp-iters",
                                             help="Override the ICP iteration count."),
        what_if: list[str] = typer.Option(
            [], "--what-if", help="KEY=VALUE[,KEY=VALUE] variant shown beside the baseline; "
            "keys are the option names (matching, inlier-ratio, solver, camera, target, ...)."),
        from_dir: Path | None = typer.Option(None, "--from",
                                             help="Result directory of `frontdiag analyze`."),
        machine: Path | None = typer.Option(None, "--machine",
                                            help="This machine's target file for --from "
                                            "(default: cached calibration, else calibrate)."),
        recalibrate: bool = typer.Option(False, "--recalibrate",
                                         help="With --from: calibrate now, refresh the cache."),
        calibrate: bool = typer.Option(False, "--calibrate",
                                       help="Measure this machine's coefficients."),
        output: Path | None = typer.Option(None, "--output", "-o",
                                           help="Where --calibrate writes the target file."),
        name: str | None = typer.Option(None, "--name", help="Name of the calibrated target."),
        repeats: int = typer.Option(15, "--repeats", help="Calibration repeats (median)."),
        as_json: bool = typer.Option(False, "--json", help="Machine-readable output."),
        markdown: bool = typer.Option(False, "--markdown", help="Markdown for a PR comment."),
        max_util: float | None = typer.Option(None, "--max-util",
                                              help="Gate: exit 1 if utilisation exceeds this."),
        max_p999_ms: float | None = typer.Option(None, "--max-p999-ms",
                                                 help="Gate (--from): exit 1 if the projected "
                                                 "p99.9 frame time exceeds this."),
        list_targets: bool = typer.Option(False, "--list-targets",
                                          help="List the shipped targets and exit."),
    ) -> int:
        return _run(dict(locals()))


def _run(o: dict) -> int:
    """Dispatch to the mode asked for; heavy imports happen here, not at --help time."""
    from frontdiag.budget import model
    from frontdiag.budget.targets import available_targets, load_target
    from frontdiag.errors import EXIT_GATE, EXIT_OK, ConfigError

    if o["as_json"] and o["markdown"]:
        raise ConfigError("--json and --markdown are exclusive; pick one")
    if o["result_dir"] is not None:
        if o["from_dir"] is not None and o["from_dir"] != o["result_dir"]:
            raise ConfigError(f"two result directories: {o['result_dir']} and --from "
                              f"{o['from_dir']}; give one")
        o["from_dir"] = o["result_dir"]
    if o["list_targets"]:
        return _emit_targets(o, available_targets())
    if o["calibrate"]:
        return _calibrate(o)
    width, height, hz = model.parse_spec(o["camera"] or "1280x720@30", "--camera")
    beams, columns, lidar_hz = (model.parse_spec(o["lidar"], "--lidar") if o["lidar"]
                                else (None, 1800, 10.0))
    workload = model.Workload(
        width=width, height=height, rate_hz=hz, features=o["features"], levels=o["levels"],
        scale=o["scale"], matching=o["matching"] or "guided", search_radius_px=o["search_radius"],
        correspondences=o["correspondences"], inlier_ratio=o["inlier_ratio"],
        confidence=o["confidence"], solver=o["solver"], pnp_points=o["pnp_points"],
        pnp_iters=o["pnp_iters"], lidar_beams=beams, lidar_columns=columns,
        lidar_rate_hz=lidar_hz, icp=o["icp"], icp_iters=o["icp_iters"]).validate()
    for gate in ("max_util", "max_p999_ms"):
        if o[gate] is not None and not o[gate] > 0:
            raise ConfigError(f"--{gate.replace('_', '-')} must be positive")
    target = load_target(o["target"])
    if o["from_dir"] is not None:
        return _measured(o, workload, target)
    if o["max_p999_ms"] is not None:
        raise ConfigError("--max-p999-ms needs measured timings (--from RESULT_DIR); the model "
                          "predicts a typical frame, not its tail")
    cmp = model.compare(workload, target, o["what_if"])
    from frontdiag.budget import render

    _emit(o, cmp.to_dict(), render.comparison_grids(cmp))
    over = [s for s in cmp.baseline.sensors
            if o["max_util"] is not None and s.utilisation > o["max_util"]]
    for s in over:
        _err(f"gate: {s.sensor} utilisation {100 * s.utilisation:.1f} % exceeds --max-util "
             f"{100 * o['max_util']:.1f} %")
    if o["max_util"] is not None and not over:
        _err(f"gate: within --max-util {100 * o['max_util']:.1f} %")
    return EXIT_GATE if over else EXIT_OK


def _err(message: str) -> None:
    from frontdiag.cli._console import make_console

    make_console(stderr=True).print(message, highlight=False, markup=False)


def _emit(o: dict, data: dict, grids: list) -> None:
    """Print JSON, markdown or rich tables: the one place this command writes to stdout."""
    import json

    from frontdiag.budget import render

    if o["as_json"]:
        typer.echo(json.dumps(data, indent=2, ensure_ascii=False))
    elif o["markdown"]:
        typer.echo("\n".join(render.to_markdown(g) for g in grids))
    else:
        from frontdiag.cli._console import make_console

        console = make_console()
        for g in grids:
            console.print(render.to_rich(g))
            console.print()


def _emit_targets(o: dict, names: list[str]) -> int:
    from frontdiag.budget.render import Grid
    from frontdiag.budget.targets import load_target, targets_dir

    targets = [load_target(n) for n in names]
    rows = tuple((t.name, t.provenance, str(len(t.coefficients)), t.description)
                 for t in targets)
    data = {"targets_dir": str(targets_dir()),
            "targets": [{"name": r[0], "provenance": r[1], "coefficients": int(r[2]),
                         "description": r[3]} for r in rows]}
    _emit(o, data, [Grid(f"Targets in {targets_dir()}",
                         ("Target", "Provenance", "Coefficients", "Description"), rows)])
    return 0


def _cache_file() -> Path:
    import os

    root = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(root) / "frontdiag" / "budget-machine.toml"


def _write_target(target, path: Path, header: str) -> None:
    from frontdiag.budget.targets import target_to_toml
    from frontdiag.errors import ConfigError

    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(target_to_toml(target, header), encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot write target file: {exc}") from exc


CALIBRATION_HEADER = (
    "Measured by `frontdiag budget --calibrate` on the machine named in [machine]:\n"
    "single-threaded microbenchmarks of the operations each coefficient stands for, seeded\n"
    "synthetic inputs, median of the repeats. Valid for this machine only.")


def _calibrate(o: dict) -> int:
    from frontdiag.budget.calibrate import calibrate
    from frontdiag.budget.render import Grid
    from frontdiag.budget.targets import COEFFICIENTS, load_target
    from frontdiag.errors import ConfigError

    if o["repeats"] < 1:
        raise ConfigError("--repeats must be at least 1")
    target = calibrate(repeats=o["repeats"], name=o["name"])
    if o["output"] is not None:
        _write_target(target, o["output"], CALIBRATION_HEADER)
    ref = load_target(o["target"])
    rows = []
    for key, c in target.coefficients.items():
        r = ref.coefficients.get(key)
        rows.append((key, f"{c.value:.4g}", COEFFICIENTS[key][0],
                     f"{r.value:.4g}" if r else "—",
                     f"{c.value / r.value:.2f}" if r else "—"))
    where = f"written to {o['output']}" if o["output"] else "not written (pass -o FILE)"
    notes = (f"{target.description}; {where}.",
             f"Ratio = this machine / {ref.name}; above 1 means this machine is slower at it.")
    data = {"target": target.name, "written_to": str(o["output"]) if o["output"] else None,
            "machine": target.machine,
            "coefficients": {k: {"value": c.value, "unit": c.unit, "source": c.source}
                             for k, c in target.coefficients.items()}}
    _emit(o, data, [Grid(f"Coefficients measured on {target.machine.get('hostname')}",
                         ("Coefficient", "This machine", "Unit", ref.name,
                          "Ratio"), tuple(rows), notes=notes)])
    return 0


def _machine(o: dict):
    """This machine's coefficients: --machine FILE, the cache, or a calibration now."""
    from frontdiag.budget.calibrate import calibrate, machine_info
    from frontdiag.budget.targets import load_target

    if o["machine"] is not None:
        return load_target(str(o["machine"])), f"from {o['machine']}"
    cache = _cache_file()
    why_not = ""  # why a cache that is there was not used, said in the note
    if cache.is_file() and not o["recalibrate"]:
        try:
            cached = load_target(str(cache))
        except Exception as exc:  # a corrupt cache is recalibrated, and the note says so
            cached, why_not = None, f"the cache could not be read ({exc}); "
        info = machine_info()
        if cached is not None:
            other = [k for k in ("hostname", "cpu", "opencv") if cached.machine.get(k) != info[k]]
            if not other:
                when = cached.machine.get("calibrated_utc", "an earlier run")
                return cached, (f"cached calibration from {when} ({cache}); --recalibrate to "
                                "refresh")
            why_not = ("the cache was made with another " + ", ".join(other) + " ("
                       + ", ".join(f"{cached.machine.get(k)!r} against {info[k]!r}"
                                   for k in other) + "); ")
    target = calibrate(repeats=o["repeats"])
    _write_target(target, cache, CALIBRATION_HEADER)
    return target, (f"{why_not}calibrated in this run ({o['repeats']} repeats), cached in "
                    f"{cache}")


def _measured(o: dict, workload, target) -> int:
    from frontdiag.budget import measured, render
    from frontdiag.errors import EXIT_GATE, EXIT_OK, ConfigError

    if o["what_if"]:
        raise ConfigError("--what-if compares derived budgets; it does not apply to --from")
    machine, note = _machine(o)
    camera_hz = workload.rate_hz if o["camera"] else None
    lidar_hz = workload.lidar_rate_hz if o["lidar"] else None
    report = measured.measured_report(o["from_dir"], workload, target, machine, note,
                                      camera_hz=camera_hz, lidar_hz=lidar_hz,
                                      matching=o["matching"])
    _emit(o, report.to_dict(), render.measured_grids(report))
    failed = measured.check_gates(report, o["max_util"], o["max_p999_ms"])
    for message in failed:
        _err("gate: " + message)
    if (o["max_util"] is not None or o["max_p999_ms"] is not None) and not failed:
        _err("gate: projected timings within the given limits")
    return EXIT_GATE if failed else EXIT_OK
