"""`frontdiag simulate`: write a labelled recording of a warehouse scenario."""

from __future__ import annotations

from pathlib import Path

import typer

from frontdiag.errors import ConfigError


def _parse_pair(text: str, what: str) -> tuple[int, int]:
    try:
        a, b = text.lower().split("x")
        return int(a), int(b)
    except ValueError as exc:
        raise ConfigError(f"{what} must look like 640x480, got {text!r}") from exc


def register(app: typer.Typer) -> None:
    """Add the command to the app."""

    @app.command("simulate", epilog="Labels: <output>.labels.csv beside the recording, header "
                 "t_start_ns,t_end_ns,condition (inclusive header-stamp intervals). "
                 "See docs/simulate.md.")
    def simulate_cmd(
        scenario: str = typer.Argument(None, help="Scenario name (see --list)."),
        output: Path = typer.Option(None, "-o", "--output", help="Recording to write."),
        fmt: str = typer.Option("mcap", "--format", "-f", metavar="[mcap|bag|db3|mcap-ros1|ros2-mcap]",
                                help="Container: mcap (plain MCAP, ROS 2 cdr), bag (ROS 1), db3 "
                                     "(ROS 2 sqlite bag folder); also mcap-ros1, ros2-mcap."),
        seconds: float = typer.Option(None, "--seconds", "-s",
                                      help="Length in seconds (default: the scenario's)."),
        seed: int = typer.Option(0, "--seed", help="Random seed; same seed, same bytes."),
        size: str = typer.Option("640x480", "--size", help="Image size WxH."),
        rate: float = typer.Option(15.0, "--rate", help="Camera rate in Hz."),
        hfov: float = typer.Option(70.0, "--hfov", help="Horizontal field of view, degrees."),
        lidar: str = typer.Option("16x1024", "--lidar",
                                  help="LiDAR BEAMSxCOLUMNS, e.g. 16x1024, 128x1800."),
        no_lidar: bool = typer.Option(False, "--no-lidar", help="Write no LiDAR."),
        compressed: str = typer.Option(None, "--compressed", metavar="[jpeg|png]",
                                       help="Publish CompressedImage: jpeg or png."),
        jpeg_quality: int = typer.Option(90, "--jpeg-quality", help="JPEG quality 1-100."),
        blur_ms: float = typer.Option(0.0, "--blur-ms",
                                      help="Motion blur: exposure time in ms (0: none)."),
        no_auto_exposure: bool = typer.Option(False, "--no-auto-exposure",
                                              help="Fix the gain (no exposure steps)."),
        list_: bool = typer.Option(False, "--list", help="List the scenarios and exit."),
        as_json: bool = typer.Option(False, "--json", help="With --list: machine-readable "
                                     "(schema docs/schemas/simulate-list.json)."),
        quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
        force: bool = typer.Option(False, "--force", help="Replace an existing output."),
        pose_graph: Path = typer.Option(None, "--pose-graph",
                                        help="Also (or only) write laps of the hall as a g2o "
                                             "pose graph with true and perceptual-aliasing false "
                                             "loops, labels in FILE.labels.csv (for `frontdiag "
                                             "loops`)."),
    ) -> int:
        """Simulate a warehouse AMR scenario and write a labelled recording.

        Example: frontdiag simulate repetitive_aisle -o aisle.mcap --seconds 20 --seed 3

        Pose graph only: frontdiag simulate --pose-graph hall.g2o --seconds 150
        """
        from rich.table import Table

        from frontdiag.cli._console import make_console
        from frontdiag.sim.lidar import LidarSpec
        from frontdiag.sim.scenarios import SCENARIOS

        console = make_console()
        if list_ and as_json:
            from frontdiag.json_models import ScenariosDoc, emit

            typer.echo(emit(ScenariosDoc, {"scenarios": [
                {"name": sc.name, "summary": sc.summary, "labels": sc.shows,
                 "default_seconds": sc.default_seconds} for sc in SCENARIOS.values()]}))
            return 0
        if list_:
            table = Table(title="frontdiag simulate scenarios")
            table.add_column("scenario", style="bold")
            table.add_column("what happens")
            table.add_column("labels (by construction)")
            table.add_column("default s", justify="right")
            for sc in SCENARIOS.values():
                table.add_row(sc.name, sc.summary, sc.shows, f"{sc.default_seconds:g}")
            console.print(table)
            return 0
        if pose_graph is not None:
            from frontdiag.sim.posegraph import warehouse_pose_graph

            if pose_graph.exists() and not force:
                raise ConfigError(f"{pose_graph} exists; pass --force to replace it")
            gpath, lpath, n = warehouse_pose_graph(pose_graph, seconds=seconds or 150.0,
                                                   seed=seed)
            console.print(f"wrote {gpath} ({n['poses']} poses, {n['true_loops']} true and "
                          f"{n['false_loops']} false loops) and {lpath}", highlight=False,
                          soft_wrap=True)
            if output is None:
                return 0
        if scenario is None:
            raise ConfigError("name a scenario", hint="frontdiag simulate --list shows them")
        if output is None:
            raise ConfigError("missing -o/--output", hint=f"e.g. -o {scenario}.mcap")
        if compressed not in (None, "jpeg", "png"):
            raise ConfigError(f"--compressed must be jpeg or png, got {compressed!r}")
        w, h = _parse_pair(size, "--size")
        spec = None
        if not no_lidar:
            beams, cols = _parse_pair(lidar, "--lidar")
            if not (1 <= beams <= 256 and 16 <= cols <= 8192):
                raise ConfigError(f"--lidar {lidar}: beams 1-256, columns 16-8192")
            spec = LidarSpec(beams=beams, columns=cols)

        from frontdiag.sim.run import SimOptions, simulate

        opts = SimOptions(seconds=seconds, seed=seed, width=w, height=h, rate_hz=rate,
                          hfov_deg=hfov, lidar=spec, compressed=compressed,
                          jpeg_quality=jpeg_quality, blur_ms=blur_ms,
                          auto_exposure=not no_auto_exposure)
        if quiet:
            res = simulate(scenario, output, fmt, opts, overwrite=force)
        else:
            from rich.progress import BarColumn, Progress, TimeRemainingColumn

            with Progress("[progress.description]{task.description}", BarColumn(),
                          "{task.completed}/{task.total} frames", TimeRemainingColumn(),
                          console=make_console(stderr=True), transient=True) as bar:
                task = bar.add_task(f"simulating {scenario}", total=None)

                def step(done: int, total: int) -> None:
                    bar.update(task, completed=done, total=total)

                res = simulate(scenario, output, fmt, opts, progress=step, overwrite=force)
        console.print(f"wrote {res.path} ({res.frames} frames, {res.scans} scans, "
                      f"{res.seconds:.1f} s) and {res.labels_path}", highlight=False,
                      soft_wrap=True)
        counts: dict[str, int] = {}
        for _, _, c in res.labels:
            counts[c] = counts.get(c, 0) + 1
        console.print("label intervals: " + ", ".join(f"{k} {v}" for k, v in sorted(
            counts.items())), highlight=False, soft_wrap=True)
        if res.exposure_steps:
            console.print(f"auto-exposure stepped {len(res.exposure_steps)} time(s)",
                          highlight=False)
        return 0
