"""`frontdiag analyze LOG`: re-run the frontend frame by frame and report what it reveals."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import typer

from frontdiag.cli import EPILOG

HELP = """Re-run the camera (and LiDAR) frontend on a recording, frame by frame.

Reads ROS 1 .bag (or a folder of split bags NAME_0.bag, NAME_1.bag, ...),
ROS 2 bag folders (.db3 or .mcap storage), standalone .db3/.mcap files and
plain MCAP (cdr or ros1 encoding, or Foxglove's schemas in Protobuf or
JSON). Cameras: Image, CompressedImage, and H.264/H.265/VP9/AV1 video
(Foxglove CompressedVideo, ffmpeg_image_transport). LiDAR: PointCloud2,
LaserScan, Livox CustomMsg, Velodyne packets. The only image topic (and
the only LiDAR topic) is taken automatically; with several, frontdiag
prints the exact --camera-topic / --lidar-topic to pass.

Examples:

  frontdiag analyze run.mcap

  frontdiag analyze run.bag --camera-topic /cam/image_raw --out results/ --format csv

  frontdiag analyze run_db3/ --start 12 --end 20 --intrinsics 615,615,320,240

  frontdiag analyze run.mcap --max-frames 300 --stride 2 --json > summary.json

  frontdiag analyze run.mcap --fail-on warn --junit report.xml --max-fraction fail=0.02

  frontdiag analyze run.mcap --out new/ --baseline old/     # fail on regressions vs old run

  frontdiag analyze run.mcap --ratio 1.0 --no-mutual --ransac-iters 40  # your frontend's budget

  frontdiag analyze 4k_run.mcap --downscale 2   # your frontend runs on half-size pictures

  frontdiag analyze long_run.mcap --jobs 2 --out results/   # both cores on one recording

  frontdiag analyze logs/ 'more/*.mcap' --out fleet/ --jobs 2   # a fleet: one folder each

  frontdiag analyze logs/ --out fleet/ --camera-topic /cam0/image_raw,/left/image_raw

  frontdiag analyze logs/ --out fleet/ --scheduler tcp://10.0.0.5:8786   # on a Dask cluster

Exit codes: 0 nothing at or above --fail-on, 1 a gate failed, 2 bad input / usage / config,
3 internal error, 130 interrupted.
"""


MAX_FEATURES = 1_000_000  # OpenCV takes a C int; beyond this no frame has that many keypoints
MAX_RANSAC_ITERS = 1_000_000


def register(app: typer.Typer) -> None:
    app.command("analyze", help=HELP, epilog=EPILOG, no_args_is_help=True)(analyze_cmd)


def analyze_cmd(
    logs: list[Path] = typer.Argument(..., metavar="LOG...",
                                      help="Recording: .bag, .db3, .mcap, or a bag folder. "
                                           "Several, a folder of recordings or a quoted glob: "
                                           "a fleet run (needs --out).",
                                      show_default=False),
    out: Path | None = typer.Option(None, "--out", "-o",
                                    help="Result directory: frames.parquet, manifest.json, "
                                         "episodes.parquet, diagnostics.mcap (and frames.csv)."),
    fmt: str = typer.Option("parquet", "--format", metavar="[parquet|csv]",
                            help="parquet (always written) or csv (adds frames.csv)."),
    camera_topic: str | None = typer.Option(None, "--camera-topic",
                                            help="Image topic (Image or CompressedImage); "
                                            "several, comma-separated: the first the recording "
                                            "holds (a fleet whose recordings name the camera "
                                            "differently)."),
    lidar_topic: str | None = typer.Option(None, "--lidar-topic",
                                           help="LiDAR topic (PointCloud2, LaserScan or Livox "
                                           "CustomMsg); several, comma-separated, as for "
                                           "--camera-topic."),
    odom_topic: str | None = typer.Option(None, "--odom-topic",
                                          help="Odometry used as the LiDAR motion prior: "
                                          "nav_msgs/Odometry, or a PoseStamped / "
                                          "PoseWithCovarianceStamped topic of the robot's "
                                          "continuous pose."),
    no_camera: bool = typer.Option(False, "--no-camera", help="Skip the camera frontend."),
    no_lidar: bool = typer.Option(False, "--no-lidar", help="Skip the LiDAR frontend."),
    intrinsics: str | None = typer.Option(None, "--intrinsics", metavar="FX,FY,CX,CY",
                                          help="fx,fy,cx,cy in pixels (overrides CameraInfo)."),
    camera_info: Path | None = typer.Option(None, "--camera-info",
                                            help="ROS camera_info YAML (overrides CameraInfo)."),
    start: float | None = typer.Option(None, "--start", help="Seconds from recording start."),
    end: float | None = typer.Option(None, "--end", help="Seconds from recording start."),
    max_frames: int | None = typer.Option(None, "--max-frames",
                                          help="Analyse at most N frames per sensor."),
    stride: int = typer.Option(1, "--stride", help="Analyse every N-th message."),
    downscale: int = typer.Option(1, "--downscale", metavar="N",
                                  help="Shrink camera pictures by N (1-8) before the frontend, "
                                       "as a frontend that runs on reduced images sees them; K "
                                       "follows."),
    config: Path | None = typer.Option(None, "--config", metavar="FILE.toml",
                                       help="Frontend parameters (\\[camera] and \\[lidar] tables; see "
                                            "docs/config.md); the options below win over it."),
    features: int | None = typer.Option(None, "--features",
                                        help="ORB features per frame (default 1000)."),
    ratio: float | None = typer.Option(None, "--ratio",
                                help="Lowe ratio threshold (0-1]; 1.0 keeps every unambiguous "
                                     "nearest neighbour. Match your frontend's setting "
                                     "(default 0.8)."),
    no_mutual: bool = typer.Option(False, "--no-mutual",
                                   help="Skip the mutual-consistency check in matching."),
    ransac_iters: int | None = typer.Option(None, "--ransac-iters",
                                            help="RANSAC iteration cap for E and H; set your "
                                                 "frontend's budget to see where it starves "
                                                 "(FD-RAN-001) (default 1000)."),
    lidar_backend: str | None = typer.Option(None, "--lidar-backend",
                                             metavar="[auto|small_gicp|open3d]",
                                      help="LiDAR registration: auto (small_gicp), small_gicp, "
                                           "or open3d (needs frontdiag\\[open3d]) (default auto)."),
    rules_dir: Path | None = typer.Option(None, "--rules", metavar="DIR",
                                          help="Your own rules directory, added to the shipped "
                                               "rules (IDs in your own namespace, e.g. MY-001)."),
    no_default_rules: bool = typer.Option(False, "--no-default-rules",
                                          help="Use only the --rules directory."),
    overrides: Path | None = typer.Option(None, "--overrides",
                                          help="TOML file overriding rule thresholds."),
    select: list[str] | None = typer.Option(None, "--select", metavar="ID",
                                            help="Only these rule IDs (repeat or comma-separate)."),
    ignore: list[str] | None = typer.Option(None, "--ignore", metavar="ID",
                                            help="Skip these rule IDs (repeat or comma-separate)."),
    no_rules: bool = typer.Option(False, "--no-rules", help="Metrics only, no verdicts."),
    fail_on: str = typer.Option("fail", "--fail-on", metavar="[warn|fail|never]",
                                help="Exit 1 when a rule of this severity fires: warn, fail, never."),
    max_fraction: list[str] | None = typer.Option(
        None, "--max-fraction", metavar="SEVERITY=SHARE", help="Run-level gate on the share of frames, e.g. fail=0.02 (verdicts "
                                                       "at or above fail) or nopose=0.05 (frames "
                                                       "the frontend estimated no motion on)."),
    baseline: Path | None = typer.Option(None, "--baseline",
                                         help="Earlier result dir of the same recording: exit 1 "
                                              "on regressions."),
    junit: Path | None = typer.Option(None, "--junit", help="Write JUnit XML (one case per rule; "
                                      "a fleet: one suite per recording)."),
    as_json: bool = typer.Option(False, "--json",
                                 help="Print a machine-readable summary on stdout."),
    jobs: int = typer.Option(1, "--jobs", "-j",
                             help="Processes: a long recording is split into time windows "
                                  "analysed in parallel (same table as one process); a fleet "
                                  "runs this many recordings at once."),
    scheduler: str | None = typer.Option(None, "--scheduler",
                                         help="Fleet on Dask: tcp://HOST:PORT of a running "
                                              "scheduler, or 'local' for a LocalCluster of "
                                              "--jobs workers (needs frontdiag\\[fleet])."),
    quiet: bool = typer.Option(False, "--quiet", "-q",
                               help="No progress bar or table; a failed gate's reasons still go "
                                    "to stderr."),
    force: bool = typer.Option(False, "--force",
                               help="Replace an earlier result in --out (refused otherwise); "
                                    "fleet: re-analyse recordings whose result is current."),
) -> int:
    from frontdiag.api import AnalysisOptions
    from frontdiag.cli._console import make_console
    from frontdiag.errors import (
        EXIT_INTERRUPTED,
        EXIT_OK,
        ConfigError,
        FrontdiagError,
        RecordingError,
    )
    from frontdiag.output import (
        check_output_file,
        guarded_write,
        prepare_out_dir,
        refuse_overwrite,
    )

    if fail_on not in ("warn", "fail", "never"):
        raise ConfigError(f"--fail-on {fail_on!r}: choose warn, fail or never")
    if lidar_backend not in (None, "auto", "small_gicp", "open3d"):
        raise ConfigError(f"--lidar-backend {lidar_backend!r}: choose auto, small_gicp or open3d")
    if fmt not in ("parquet", "csv"):
        raise ConfigError(f"--format {fmt!r}: choose parquet or csv")
    if features is not None and features < 50:
        raise ConfigError(f"--features {features}: need at least 50")
    if ratio is not None and not 0.0 < ratio <= 1.0:
        raise ConfigError(f"--ratio {ratio:g}: choose a value in (0, 1]")
    if ransac_iters is not None and not 1 <= ransac_iters <= MAX_RANSAC_ITERS:
        raise ConfigError(f"--ransac-iters {ransac_iters}: choose 1 to {MAX_RANSAC_ITERS}")
    if features is not None and features > MAX_FEATURES:
        raise ConfigError(f"--features {features}: at most {MAX_FEATURES}")
    if no_default_rules and rules_dir is None:
        raise ConfigError("--no-default-rules needs --rules DIR (the rules to use instead)")
    from frontdiag.config import load_config

    cfg = load_config(config, {
        "camera": {"n_features": features, "ratio": ratio,
                   "mutual": False if no_mutual else None, "ransac_max_iters": ransac_iters},
        "lidar": {"backend": lidar_backend}})
    if jobs < 1:
        raise ConfigError(f"--jobs {jobs}: need at least 1")
    from frontdiag.cli.fleet_ import is_fleet

    fleet = is_fleet(logs, scheduler)
    log = logs[0]
    if out is not None and not fleet:
        refuse_overwrite(out, force)
    # every output location is checked before the recording is read, so a bad one costs nothing
    out_dir = None if out is None or fleet else prepare_out_dir(out, [log])
    if junit is not None and not fleet:
        check_output_file(junit, "--junit", [log])
    opts = AnalysisOptions(
        camera_topic=camera_topic, lidar_topic=lidar_topic, odom_topic=odom_topic,
        use_camera=not no_camera, use_lidar=not no_lidar, intrinsics=intrinsics,
        camera_info_file=str(camera_info) if camera_info else None, start_s=start, end_s=end,
        max_frames=max_frames, stride=stride, camera_params=cfg.camera_params(),
        lidar_params=cfg.lidar_params(), rules=not no_rules,
        rules_dir=str(rules_dir) if rules_dir and no_default_rules else None,
        rules_extra=[str(rules_dir)] if rules_dir and not no_default_rules else None,
        rules_overrides=str(overrides) if overrides else None, select=_split(select),
        ignore=_split(ignore), jobs=jobs, downscale=downscale)
    if fleet:
        from frontdiag.cli.fleet_ import run_fleet

        if baseline or max_fraction:
            raise ConfigError("--baseline and --max-fraction apply to one recording",
                              hint="analyse that recording on its own to use them")
        return run_fleet(logs, out, opts, jobs=jobs, scheduler=scheduler, fail_on=fail_on,
                         csv=(fmt == "csv"), force=force, as_json=as_json, quiet=quiet,
                         junit=junit)
    limits = None
    if max_fraction:
        from frontdiag.verdicts import parse_max_fraction

        limits = parse_max_fraction(max_fraction)
    err = make_console(stderr=True)
    diag = None
    if out_dir is not None:
        from frontdiag.report.mcap_ import DIAGNOSTICS_FILE, DiagnosticsWriter

        diag = DiagnosticsWriter(out_dir / DIAGNOSTICS_FILE)
        diag.open()
        from frontdiag.parallel import remove_stale_parts

        remove_stale_parts(out_dir)  # left by a split run killed outright, whatever this run is
    try:
        result = _run_with_progress(log, opts, err, show=not quiet and not as_json, sink=diag)
    except BaseException as exc:
        if diag is not None:  # nothing analysed: no half-written file left behind
            diag.close()
            diag.path.unlink(missing_ok=True)
        if isinstance(exc, FrontdiagError):
            raise _naming(log, exc) from exc
        raise
    gate_result = None
    if result.verdicts is not None:
        from frontdiag.verdicts import gate

        gate_result = gate(result.verdicts, fail_on=fail_on,  # type: ignore[arg-type]
                           max_fraction=limits, baseline=baseline)
    if result.interrupted or result.fault is not None:
        gate_result = _incomplete(gate_result, result)
    written: list[Path] = []
    if out_dir is not None:
        written += guarded_write(out_dir, lambda: _write_results(out_dir, result, fmt))
    if diag is not None:
        diag.finish(result.table, result.verdicts, result.ruleset)
        written.append(diag.path)
    if junit is not None and gate_result is not None:
        from frontdiag.report import write_junit

        written.append(guarded_write(junit, lambda: write_junit(
            junit, result.verdicts, gate_result, suite=_suite_name(log))))
    if as_json:
        typer.echo(_json_summary(result, gate_result, written))
    elif not quiet:
        from frontdiag.cli._render import render_analysis

        con = make_console()
        render_analysis(con, result, out_dir, written)
        if gate_result is not None:
            from frontdiag.report import reanalyse_command, render_console_summary

            render_console_summary(
                con, result.verdicts, gate_result,
                reanalyse_cmd=lambda e: reanalyse_command(str(log), e, out_base=out_dir))
    if quiet and gate_result is not None and not gate_result.passed:
        # the gate's own reasons; an interruption or damage is reported on its own line below
        reasons = [r for r in gate_result.reasons if r != gate_result.incomplete]
        if reasons:
            err.print(f"gate failed (fail-on {gate_result.fail_on}):", highlight=False)
        for reason in reasons:
            err.print(f"  - {reason}", highlight=False, markup=False, soft_wrap=True)
    if result.interrupted:
        err.print("[yellow]interrupted[/]: the frames analysed so far were kept"
                  + ("" if written else " in memory only (no --out, nothing saved)"))
        return EXIT_INTERRUPTED
    if isinstance(result.fault, RecordingError):
        # one line: the file, the damage, and what was kept
        kept = (f"{len(result.table)} frames, before it and in the parts after it, were "
                "analysed" if result.fault.resumed else
                f"{len(result.table)} frames before it were analysed")
        kept += f" and written to {out_dir}" if out_dir is not None else " (pass --out to keep them)"
        raise FrontdiagError(f"{result.fault}; {kept}")
    if result.fault is not None:
        raise _naming(log, result.fault)
    return gate_result.exit_code if gate_result is not None else EXIT_OK


def _suite_name(log: Path) -> str:
    """JUnit suite name: the recording's file (or bag folder) name."""
    return f"frontdiag {log.resolve().name or log}"


def _incomplete(gate_result: Any, result: Any) -> Any:
    """A run that did not reach the end of the recording cannot pass its gate: the verdicts
    cover only the frames before the interruption or the damage."""
    if gate_result is None:
        return None
    from dataclasses import replace

    from frontdiag.errors import EXIT_INTERRUPTED

    if result.interrupted:
        why, code = "interrupted: the verdicts cover only the frames analysed before Ctrl-C (or SIGTERM)", \
            EXIT_INTERRUPTED
    else:
        span = "the frames read" if getattr(result.fault, "resumed", False) else \
            "the frames before it"
        why, code = f"input damaged: the verdicts cover only {span} ({result.fault})", \
            getattr(result.fault, "exit_code", 2)
    return replace(gate_result, exit_code=code, reasons=[*gate_result.reasons, why],
                   incomplete=why)


def _naming(log: Path, exc: Any) -> Any:
    """The error itself when it names the recording; else the same error class and exit code
    with the recording's path in front, so every failure says which input it is about."""
    if str(log) in str(exc) or str(exc).startswith("--"):  # named, or about an option
        return exc
    from frontdiag.errors import FrontdiagError

    named = FrontdiagError(f"{log}: {exc}", hint=exc.hint)
    named.exit_code = exc.exit_code
    return named


def _write_results(out_dir: Path, result: Any, fmt: str) -> list[Path]:
    from frontdiag.output import write_frontend_config, write_manifest, write_table

    written = list(write_table(out_dir, result.table, csv=(fmt == "csv")))
    written.append(write_manifest(out_dir, result.manifest))
    written.append(write_frontend_config(out_dir, result.manifest))
    if result.verdicts is not None:
        from frontdiag.report import write_episodes, write_rules_snapshot

        written.append(write_episodes(out_dir, result.verdicts))
        written.append(write_rules_snapshot(out_dir, result.ruleset))
    return written


def _split(values: list[str] | None) -> list[str] | None:
    if not values:
        return None
    return [v.strip() for item in values for v in item.split(",") if v.strip()]


def _run_with_progress(log: Path, opts: Any, err: Any, show: bool, sink: Any = None) -> Any:
    from rich.markup import escape
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    from frontdiag.api import run_analysis

    if not show:
        return run_analysis(log, opts, sink=sink)
    with Progress(TextColumn("[bold]analyze[/] {task.description}"), BarColumn(),
                  MofNCompleteColumn(), TextColumn("frames"), TimeElapsedColumn(),
                  TimeRemainingColumn(), console=err, transient=True) as bar:
        task = bar.add_task(escape(log.name), total=None)

        def progress(done: int, expected: int | None) -> None:
            bar.update(task, completed=done, total=expected)

        return run_analysis(log, opts, progress=progress, sink=sink)


def _json_summary(result: Any, gate_result: Any, written: list[Path]) -> str:
    from frontdiag.cli._render import sensor_summaries
    from frontdiag.json_models import AnalyzeDoc, emit

    out = {"input": result.manifest["input"], "topics": result.manifest["topics"],
           "counts": result.manifest["counts"], "notes": result.notes,
           "fault": None if result.fault is None else str(result.fault),
           "interrupted": bool(result.interrupted),
           "written": [str(p) for p in written],
           "sensors": sensor_summaries(result.table)}
    if gate_result is not None:
        from frontdiag.report import to_json

        out["verdicts"] = to_json(result.verdicts, gate_result)
    return emit(AnalyzeDoc, json.loads(json.dumps(out, default=str)))
