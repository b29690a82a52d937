"""Many recordings: one result folder each and a fleet summary, on local processes or Dask.

Each recording is one task (:func:`analyse_one`): it is analysed in one process, its result
folder written (``frames.parquet``, ``manifest.json``, ``episodes.parquet``, ``rules.json``)
and one summary row returned. A result folder also holds ``fleet.json``: the recording's content
hash and the rules and options it was analysed with; a later run with the same three skips the
recording and reads its row back (resume). A recording that cannot be read becomes a row with
its error; the others go on. The tasks run on a local process pool, or on Dask distributed
(``scheduler="local"`` starts a ``LocalCluster``; ``tcp://HOST:PORT`` joins a running one, whose
workers must see the recordings and the output folder at the same paths).
"""

from __future__ import annotations

import glob
import hashlib
import json
import logging
import time
from collections.abc import Callable, Iterable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor
from dataclasses import asdict, dataclass, replace
from functools import partial
from pathlib import Path
from typing import Any

import pandas as pd

from frontdiag import __version__
from frontdiag.errors import EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_OK, ConfigError, FrontdiagError
from frontdiag.io.readers import (
    FLEET_SUMMARY_FILE,
    RECORDING_SUFFIXES,
    is_result_dir,
    recording_files,
    recording_kind,
    recording_size,
    recordings_in,
    refuse_result_dir,
    ros2_parts,
    split_parts,
)

log = logging.getLogger(__name__)

SUMMARY_FILE = FLEET_SUMMARY_FILE
STAMP_FILE = "fleet.json"
SUMMARY_COLUMNS = ["recording", "path", "status", "frames", "coverage", "ok", "warn", "fail",
                   "no_pose", "episodes", "gate", "exit_code", "seconds", "error"]


def is_recording(path: Path) -> bool:
    """Whether ``path`` is one recording (a file, a ROS 2 bag folder, split ROS 1 bags)."""
    from frontdiag.io.readers import plan

    try:
        plan(path)
    except FrontdiagError:
        return False
    return True


def discover(inputs: Iterable[str | Path], skipped: list[Path] | None = None) -> list[Path]:
    """Recordings named by files, folders of recordings and glob patterns, in a stable order.

    A folder that is itself a recording (a ROS 2 bag folder, a folder of split .bag files) is
    one recording; any other folder is searched one level deep for recording files and bag
    folders. A name that matches nothing is an error (a typo should not give an empty fleet).
    Files that are neither named like a recording (.bag, .mcap, .db3) nor start like one (a
    glob's or the shell's ``logs/*`` also catches labels and notes) are left out, and listed in
    ``skipped`` when it is given; a damaged ``run.mcap`` is kept, to be reported.
    """
    found: list[Path] = []
    inputs = list(inputs)
    for item in inputs:
        text = str(item)
        # a path that exists is itself, even when its name holds glob characters ([cam1], ?)
        paths = [Path(p) for p in sorted(glob.glob(text))] \
            if glob.has_magic(text) and not Path(text).exists() else [Path(text)]
        if not paths or not paths[0].exists():
            raise ConfigError(f"{text}: no such file, folder or matching recording",
                              hint="pass recordings, folders of recordings or a quoted glob")
        for p in paths:
            if p.is_dir() and is_result_dir(p):
                if len(paths) == 1 and paths[0] == Path(text):  # named, not globbed
                    refuse_result_dir(p)
                if skipped is not None:
                    skipped.append(p)
                continue
            if p.is_file() and p.suffix not in RECORDING_SUFFIXES \
                    and recording_kind(p) in (None, "zstd"):
                if skipped is not None:
                    skipped.append(p)
                continue
            if p.is_dir() and not (p / "metadata.yaml").exists() and not split_parts(p) \
                    and not ros2_parts(p):
                found += recordings_in(p)
            else:
                found.append(p)
    out = list(dict.fromkeys(p.resolve() for p in found))
    if not out:
        raise ConfigError(f"no recording (.bag, .mcap, .db3, bag folder) in {', '.join(map(str, inputs))}")
    return out


def discover_quietly(folder: Path) -> list[Path]:
    """:func:`discover` of one folder, empty where it finds no recording."""
    try:
        return discover([folder])
    except ConfigError:
        return []


def result_names(paths: list[Path]) -> list[str]:
    """One folder name per recording: its name without suffix, made unique by a path hash."""
    stems = [p.name[: -len(p.suffix)] if p.suffix in RECORDING_SUFFIXES else p.name
             for p in paths]
    return [s if stems.count(s) == 1 else f"{s}-{hashlib.sha1(str(p).encode()).hexdigest()[:6]}"
            for s, p in zip(stems, paths, strict=True)]


def content_hash(path: Path) -> str:
    """BLAKE2b of the recording's bytes (every file of a folder, by relative name)."""
    h = hashlib.blake2b(digest_size=16)
    for f in recording_files(path):
        h.update(str(f.relative_to(path) if path.is_dir() else f.name).encode())
        with open(f, "rb") as fh:
            while chunk := fh.read(1 << 20):
                h.update(chunk)
    return h.hexdigest()


def setup_hash(opts: Any) -> str:
    """What decides a result besides the recording: frontdiag, the rules as loaded (after
    overrides and selection) and the analysis options (the number of processes aside)."""
    from frontdiag.verdicts import load_ruleset

    rules: Any = None
    if opts.rules:
        rules = load_ruleset(Path(opts.rules_dir) if opts.rules_dir else None,
                             Path(opts.rules_overrides) if opts.rules_overrides else None,
                             select=opts.select, ignore=opts.ignore,
                             extra_dirs=[Path(d) for d in opts.rules_extra or ()]).to_dict()
    options = asdict(replace(opts, jobs=1))
    blob = json.dumps({"frontdiag": __version__, "rules": rules, "options": options},
                      sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class Task:
    """One recording of a fleet run (picklable: it travels to a worker)."""

    path: Path
    out: Path  # its result folder
    opts: Any  # AnalysisOptions
    setup: str  # setup_hash(opts)
    fail_on: str = "fail"
    csv: bool = False
    force: bool = False


def analyse_one(task: Task, slot: int | None = None,
                progress: Callable[[int, int | None], None] | None = None) -> dict[str, Any]:
    """Analyse one recording into its result folder and return its summary row; a recording
    whose folder already holds a result of the same content, rules and options is skipped.
    ``progress(done, expected)`` sees the frames analysed; in a pool worker ``slot`` says
    where in the worker's shared counters they go instead (:func:`run_local`)."""
    from frontdiag import parallel

    with parallel.interruptible(), parallel.one_core():
        return _analyse_one(task, parallel.task_progress(slot) or progress)


def _analyse_one(task: Task, progress: Callable[[int, int | None], None] | None = None
                 ) -> dict[str, Any]:
    t0 = time.perf_counter()
    name = task.out.name
    row: dict[str, Any] = {"recording": name, "path": str(task.path)}
    try:
        digest = content_hash(task.path)
        stamp = task.out / STAMP_FILE
        if not task.force and stamp.exists():
            old = json.loads(stamp.read_text())
            if old.get("content") == digest and old.get("setup") == task.setup \
                    and (task.out / "frames.parquet").exists():
                return _complete({**old["summary"], "status": "skipped",
                                  "path": str(task.path)})
        row.update(_analyse(task, progress))
        row["status"] = "error" if row.get("error") else "ok"
        row["seconds"] = round(time.perf_counter() - t0, 3)
        if row["status"] == "ok":
            stamp.write_text(json.dumps({"content": digest, "setup": task.setup,
                                         "summary": _complete(row)}, indent=1, default=str)
                             + "\n")
    except FrontdiagError as exc:
        row.update(status="error", error=str(exc), exit_code=exc.exit_code)
    except Exception as exc:  # a bug on one recording must not stop the others
        log.exception("internal error on %s", task.path)
        row.update(status="error", error=f"internal error: {exc}", exit_code=EXIT_INTERNAL)
    row["seconds"] = round(time.perf_counter() - t0, 3)
    return _complete(row)


def _analyse(task: Task, progress: Callable[[int, int | None], None] | None = None
             ) -> dict[str, Any]:
    from frontdiag.api import run_analysis
    from frontdiag.output import write_manifest, write_table
    from frontdiag.report import write_episodes, write_rules_snapshot
    from frontdiag.verdicts import gate

    result = run_analysis(task.path, task.opts, progress=progress)
    task.out.mkdir(parents=True, exist_ok=True)
    write_table(task.out, result.table, csv=task.csv)
    write_manifest(task.out, result.manifest)
    row: dict[str, Any] = summarise(result.table, result.manifest)
    if result.verdicts is not None:
        write_episodes(task.out, result.verdicts)
        write_rules_snapshot(task.out, result.ruleset)
        g = gate(result.verdicts, fail_on=task.fail_on)  # type: ignore[arg-type]
        row.update(episodes=len(result.verdicts.episodes),
                   gate="passed" if g.passed else "failed", exit_code=g.exit_code)
    # the frames before the damage or the interruption are kept, but their verdicts cover only
    # part of the recording: such a gate is never "passed"
    if result.fault is not None:
        row.update(error=str(result.fault), exit_code=result.fault.exit_code, gate="incomplete")
    elif result.interrupted:
        row.update(error="interrupted", exit_code=EXIT_INTERRUPTED, gate="incomplete")
    return row


def summarise(table: pd.DataFrame, manifest: dict[str, Any]) -> dict[str, Any]:
    """Frames analysed, coverage (analysed / messages on the analysed topics), frames per
    verdict, and frames on which the frontend estimated no motion (``no_pose``)."""
    from frontdiag.verdicts.gate import no_pose

    counts = manifest.get("counts", {})
    messages = sum(c.get("messages", 0) for c in counts.values())
    analysed = sum(c.get("analysed", 0) for c in counts.values())
    row: dict[str, Any] = {"frames": len(table),
                           "coverage": round(analysed / messages, 4) if messages else None}
    if "verdict" in table.columns:
        vc = table["verdict"].value_counts()
        row.update({k: int(vc.get(k, 0)) for k in ("ok", "warn", "fail")})
    row["no_pose"] = no_pose(table).frames
    return row


def _complete(row: dict[str, Any]) -> dict[str, Any]:
    defaults: dict[str, Any] = {"frames": 0, "coverage": None, "ok": 0, "warn": 0, "fail": 0,
                                "episodes": 0, "gate": "", "exit_code": EXIT_OK, "seconds": 0.0,
                                "error": ""}
    return {c: row.get(c, defaults.get(c)) if row.get(c) is not None else defaults.get(c)
            for c in SUMMARY_COLUMNS}


def plan_tasks(inputs: Iterable[str | Path], out: Path, opts: Any, *, fail_on: str = "fail",
               csv: bool = False, force: bool = False,
               skipped: list[Path] | None = None) -> list[Task]:
    paths = discover(inputs, skipped)
    setup = setup_hash(opts)
    one = replace(opts, jobs=1)
    return [Task(p, out / n, one, setup, fail_on, csv, force)
            for p, n in zip(paths, result_names(paths), strict=True)]


RowFn = Callable[[dict[str, Any]], None]
FramesFn = Callable[[int, int, "int | None"], None]
"""``(task index, frames analysed, frames expected or None)`` of a recording being analysed."""


def interrupted(row: dict[str, Any]) -> bool:
    """Whether a recording's analysis was stopped by Ctrl-C (or SIGTERM)."""
    return row.get("error") == "interrupted"


def _size_or_zero(path: Path) -> int:
    try:
        return recording_size(path)
    except OSError:  # reported when its task runs
        return 0


def largest_first(tasks: list[Task]) -> list[int]:
    """The order in which to hand the tasks out: largest recording first (ties in the given
    order). The work is spread greedily over the workers as they come free, so a large
    recording started last would leave the others idle while it runs alone; started first, the
    small ones fill in around it (longest-processing-time-first scheduling, Graham 1969). The
    size on disk stands in for the work: frames times pixels, compressed alike within a fleet."""
    size = [_size_or_zero(t.path) for t in tasks]
    return sorted(range(len(tasks)), key=lambda i: -size[i])


def run_local(tasks: list[Task], jobs: int, on_row: RowFn | None = None,
              on_frames: FramesFn | None = None) -> list[dict[str, Any]]:
    """The tasks on ``jobs`` local processes (in this process when ``jobs`` is 1).
    ``on_frames`` sees the frames analysed of each recording under way (every
    ``PROGRESS_POLL_S`` from the workers).

    Ctrl-C stops the fleet: no further recording is started, the recordings being analysed keep
    the frames analysed so far (a row marked interrupted), and the rows of the finished ones are
    returned, so the caller can write the summary of what was done."""
    rows: list[dict[str, Any] | None] = [None] * len(tasks)

    def take(i: int, row: dict[str, Any]) -> bool:
        rows[i] = row
        if on_row:
            on_row(row)
        return interrupted(row)

    if jobs <= 1 or len(tasks) == 1:
        try:
            for i, t in enumerate(tasks):
                frames = None if on_frames is None else partial(on_frames, i)
                if take(i, analyse_one(t, progress=frames)):
                    break
        except KeyboardInterrupt:  # between two recordings, or while writing one's results
            pass
    else:
        from frontdiag.parallel import (
            FLEET_PRELOAD,
            PROGRESS_POLL_S,
            _context,
            drain,
            shared_counters,
            wait,
            worker_init,
        )

        ctx = _context(FLEET_PRELOAD)
        counters = shared_counters(ctx, len(tasks))  # each recording's frames, as it goes
        pool = ProcessPoolExecutor(max_workers=jobs, mp_context=ctx,
                                   initializer=worker_init, initargs=(counters,))
        futs = {pool.submit(analyse_one, tasks[i], i): i for i in largest_first(tasks)}
        stop = False
        try:
            pending = set(futs)
            while pending and not stop:
                finished, pending = wait(pending, timeout=PROGRESS_POLL_S,
                                         return_when=FIRST_COMPLETED)
                for fut in finished:
                    if take(futs[fut], fut.result()):
                        stop = True
                        break
                if on_frames is not None and not stop:
                    for fut in pending:
                        i = futs[fut]
                        if counters[2 * i]:
                            on_frames(i, counters[2 * i], counters[2 * i + 1] or None)
        except KeyboardInterrupt:
            stop = True
        finally:
            if stop:  # queued recordings never start; running ones hand back their frames
                drain(pool, list(futs))
            pool.shutdown(wait=not stop, cancel_futures=stop)
        for fut, i in futs.items():
            if rows[i] is None and fut.done() and not fut.cancelled() and fut.exception() is None:
                take(i, fut.result())
    return [r for r in rows if r is not None]


def run_dask(tasks: list[Task], scheduler: str, jobs: int, on_row: RowFn | None = None,
             cluster_kwargs: dict[str, Any] | None = None) -> list[dict[str, Any]]:
    """The tasks on Dask distributed: ``scheduler`` is ``local`` (a LocalCluster of ``jobs``
    single-threaded workers) or the address of a running scheduler."""
    try:
        from dask.distributed import Client, LocalCluster
        from dask.distributed import as_completed as dask_completed
    except ImportError as exc:
        from frontdiag.errors import OptionalDependencyError

        raise OptionalDependencyError(
            "--scheduler needs Dask distributed", hint="pip install 'frontdiag[fleet]'") from exc
    cluster = None
    if scheduler == "local":
        kw = {"n_workers": max(jobs, 1), "threads_per_worker": 1, "dashboard_address": None}
        kw.update(cluster_kwargs or {})
        cluster = LocalCluster(**kw)
        client = Client(cluster)
    else:
        try:
            client = Client(scheduler, timeout="10s")
        except OSError as exc:
            raise ConfigError(f"--scheduler {scheduler}: cannot connect ({exc})",
                              hint="start one with `dask scheduler` and `dask worker ADDRESS`, "
                                   "or pass --scheduler local") from exc
    try:
        order = largest_first(tasks)
        futs = client.map(analyse_one, [tasks[i] for i in order], pure=False)
        index = {f.key: i for i, f in zip(order, futs, strict=True)}
        rows: list[dict[str, Any] | None] = [None] * len(tasks)
        try:
            for fut in dask_completed(futs):
                rows[index[fut.key]] = fut.result()
                if on_row:
                    on_row(rows[index[fut.key]])  # type: ignore[arg-type]
        except KeyboardInterrupt:  # stop the fleet: what finished is kept, the rest cancelled
            client.cancel([f for f in futs if rows[index[f.key]] is None])
        return [r for r in rows if r is not None]
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def summary_table(rows: list[dict[str, Any]]) -> pd.DataFrame:
    return pd.DataFrame(rows, columns=SUMMARY_COLUMNS)


def write_summary(out: Path, rows: list[dict[str, Any]]) -> Path:
    path = out / SUMMARY_FILE
    summary_table(rows).to_parquet(path, index=False)
    return path


def is_fleet_out(folder: Path | str) -> bool:
    """Whether ``folder`` is the ``--out`` folder of a fleet run (it holds the summary)."""
    return (Path(folder) / SUMMARY_FILE).is_file()


def read_summary(folder: Path | str) -> pd.DataFrame:
    """The summary of a fleet run's ``--out`` folder, one row per recording."""
    return pd.read_parquet(Path(folder) / SUMMARY_FILE)


def worst_exit(rows: list[dict[str, Any]]) -> int:
    """The fleet's exit code: the worst of its recordings' (gate 1, bad input 2, bug 3)."""
    return max((int(r.get("exit_code") or 0) for r in rows), default=EXIT_OK)
