"""Write an analysis to a result directory that describes itself.

``frames.parquet`` always, ``frames.csv`` on request, ``manifest.json`` with versions,
effective parameters, input, topics and skip counts. List columns (``conditions``, ``rules``)
stay lists in parquet and become ``;``-separated strings in CSV.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from frontdiag.errors import ConfigError, OutputError, RecordingError

LIST_COLUMNS = ("conditions", "rules")
VECTOR_COLUMNS = ("lidar_weak_vec",)
"""Columns holding a list of floats per row (None where not computed)."""


def _vector(v: Any) -> list[float] | None:
    if isinstance(v, list | tuple | np.ndarray):
        return [float(x) for x in v]
    return None


RESULT_FILES = ("frames.parquet", "frames.csv", "manifest.json", "episodes.parquet", "rules.json")
"""Every file ``analyze --out`` may write; each must be writable before the recording is read."""


def _inside(path: Path, inputs: list[Path]) -> Path | None:
    """The input that ``path`` is, or lies inside (an input folder), if any."""
    target = path.resolve()
    for inp in inputs:
        try:
            inp_r = inp.resolve()
        except OSError:
            continue
        if target == inp_r or inp_r in target.parents:
            return inp
    return None


def _probe_dir(folder: Path, option: str) -> None:
    """Raise OutputError unless a file can be created in ``folder`` (works for root as well)."""
    try:
        fd, probe = tempfile.mkstemp(prefix=".frontdiag-probe-", dir=folder)
    except OSError as exc:
        raise OutputError(folder, f"{option}: cannot write here ({exc.strerror or exc})",
                          hint="choose a folder you can write to") from exc
    os.close(fd)
    os.unlink(probe)


def _make_dir(folder: Path, option: str) -> None:
    for parent in (folder, *folder.parents):
        if parent.exists():
            if not parent.is_dir():
                raise OutputError(folder, f"{option}: {parent} is a file, not a folder",
                                  hint="choose another location")
            break
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(folder, f"{option}: cannot create the folder ({exc.strerror or exc})",
                          hint="choose a folder you can write to") from exc


def prepare_out_dir(out: Path, inputs: list[Path], files: tuple[str, ...] = RESULT_FILES) -> Path:
    """Create the result directory and check it can take every result file, before any work.

    Refuses a directory that is, or lies inside, an input recording.
    """
    out = Path(out)
    inp = _inside(out, inputs)
    if inp is not None:
        raise OutputError(out, f"--out would write inside the input recording {inp}",
                          hint="choose another directory")
    if out.exists() and not out.is_dir():
        raise OutputError(out, "--out exists and is not a directory",
                          hint="choose another directory")
    _make_dir(out, "--out")
    for name in files:
        if (out / name).is_dir():
            raise OutputError(out / name, "--out: a folder is in the way of this result file",
                              hint="remove it or choose another --out")
    _probe_dir(out, "--out")
    return out


def refuse_overwrite(out: Path, force: bool) -> None:
    """Stop before any work when ``out`` already holds a result, unless ``force``.

    A result directory is what `explain`, `eval` and `--baseline` read later; replacing it by
    accident loses the run it describes.
    """
    out = Path(out)
    if force or not out.is_dir():
        return
    found = [name for name in RESULT_FILES if (out / name).exists()]
    if found:
        made_from = read_manifest(out).get("input", {}) if (out / "manifest.json").is_file() \
            else {}
        src = made_from.get("path") if isinstance(made_from, dict) else None
        raise ConfigError(f"--out {out}: already holds a result ({', '.join(found)}"
                          + (f", from {src}" if src else "") + ")",
                          hint="pass --force to replace it, or choose another --out directory")


def check_output_file(path: Path, option: str, inputs: list[Path],
                      what: str = "recording") -> Path:
    """Check that a single output file (``--junit``) can be written and is not an input
    (``what`` names the kind of input in the message)."""
    path = Path(path)
    inp = _inside(path, inputs)
    if inp is not None:
        raise OutputError(path, f"{option} would overwrite the input {what} {inp}"
                          if path.resolve() == inp.resolve() else
                          f"{option} would write inside the input {what} {inp}",
                          hint="choose another file name")
    if path.is_dir():
        raise OutputError(path, f"{option}: is a folder, not a file", hint="name a file")
    _make_dir(path.parent, option)
    _probe_dir(path.parent, option)
    return path


def guarded_write(path: Path, write: Callable[[], Any]) -> Any:
    """Run ``write``; an OS failure (disk full, permissions changed) becomes one OutputError."""
    try:
        return write()
    except OSError as exc:
        raise OutputError(path, f"cannot write ({exc.strerror or exc})",
                          hint="the analysis itself finished; free space or choose another "
                               "location and rerun") from exc


def without_attrs(table: pd.DataFrame) -> pd.DataFrame:
    """A shallow copy of ``table`` without its attrs: pandas deep-copies ``attrs`` (the run's
    manifest) into every column it hands out, 0.2 ms a column read, some 1 000 reads to write
    one run's files and diagnostics.mcap (as ``verdicts.engine.evaluate`` does for the rules)."""
    df = table.copy(deep=False)
    df.attrs = {}
    return df


def _csv_frame(table: pd.DataFrame) -> pd.DataFrame:
    df = without_attrs(table)
    for col in LIST_COLUMNS:
        if col in df.columns:
            df[col] = df[col].map(lambda v: ";".join(v) if isinstance(v, list | tuple | np.ndarray)
                                  else ("" if v is None or (isinstance(v, float) and np.isnan(v))
                                        else str(v)))
    for col in VECTOR_COLUMNS:
        if col in df.columns:
            df[col] = df[col].map(lambda v: "" if _vector(v) is None
                                  else " ".join(f"{x:g}" for x in _vector(v) or []))
    return df


def write_table(out: Path, table: pd.DataFrame, csv: bool = False) -> list[Path]:
    written = [out / "frames.parquet"]
    df = without_attrs(table)  # the columns converted below are replaced, not written into
    # mixed object columns (strings with NaN) must be strings for parquet
    for col in df.columns:
        if col in VECTOR_COLUMNS:
            df[col] = df[col].map(_vector)
        elif df[col].dtype == object and col not in LIST_COLUMNS:
            df[col] = df[col].map(lambda v: None if v is None or (isinstance(v, float)
                                                                  and np.isnan(v)) else str(v))
    _write_parquet(df, written[0], table.attrs)
    if csv:
        written.append(out / "frames.csv")
        _csv_frame(table).to_csv(written[1], index=False)
    return written


PARQUET_ROWS = 8192
"""Rows per row group of ``frames.parquet``: Arrow holds one group's copy at a time instead of
the whole table's (about the table's own size, 27 MiB at 30 000 frames)."""


def _write_parquet(df: pd.DataFrame, path: Path, attrs: Mapping[Any, Any] | None = None) -> None:
    """``df.to_parquet(path, index=False)`` group by group: the same file for a reader (types
    from the whole table, so a column whose first rows hold only None still reads as the lists
    or strings of the rest; ``attrs``, by default ``df.attrs``, in the metadata as pandas
    stores them)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    attrs = dict(df.attrs if attrs is None else attrs)
    schema = pa.Schema.from_pandas(df, preserve_index=False)
    if attrs:
        schema = schema.with_metadata({**(schema.metadata or {}),
                                       b"PANDAS_ATTRS": json.dumps(attrs).encode()})
    with pq.ParquetWriter(path, schema) as writer:
        for start in range(0, max(len(df), 1), PARQUET_ROWS):
            part = df.iloc[start:start + PARQUET_ROWS]
            writer.write_table(pa.Table.from_pandas(part, schema=schema, preserve_index=False))


def write_manifest(out: Path, manifest: dict[str, Any]) -> Path:
    path = out / "manifest.json"
    path.write_text(json.dumps(manifest, indent=2, default=_json_default) + "\n")
    return path


def write_frontend_config(out: Path, manifest: dict[str, Any]) -> Path:
    """The effective frontend parameters as ``frontend.toml``, which ``--config`` reads back."""
    from frontdiag.config import dump_toml

    path = out / "frontend.toml"
    path.write_text(dump_toml(manifest.get("params") or {}))
    return path


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    return str(obj)


def result_dir_hint(d: Path, default: str) -> str:
    """What to pass instead of ``d``, a folder with no frames table: one recording's folder when
    ``d`` is the ``--out`` folder of a fleet run (it holds ``fleet_summary.parquet`` and a folder
    per recording), else ``default``."""
    from frontdiag.fleet import is_fleet_out

    if not is_fleet_out(d):
        return default
    names = sorted(c.name for c in Path(d).iterdir() if (c / "frames.parquet").is_file())
    if not names:
        return f"{d} is a fleet run's folder with no finished recording; {default}"
    return (f"{d} is a fleet run's folder ({len(names)} recordings): pass one recording's "
            f"folder, e.g. {Path(d) / names[0]}")


def read_table(result: Path) -> pd.DataFrame:
    """Read ``frames.parquet`` (or ``frames.csv``) from a result directory or file."""
    result = Path(result)
    if result.is_dir():
        for name in ("frames.parquet", "frames.csv"):
            if (result / name).exists():
                return read_table(result / name)
        raise RecordingError(result, "no frames.parquet or frames.csv in this directory",
                             hint=result_dir_hint(result,
                                                  "write one with `frontdiag analyze LOG --out DIR`"))
    if not result.exists():
        raise RecordingError(result, "no such file or folder")
    try:
        if result.suffix == ".csv":
            df = pd.read_csv(result)
            for col in LIST_COLUMNS:
                if col in df.columns:
                    df[col] = df[col].map(lambda v: [] if not isinstance(v, str) or not v
                                          else v.split(";"))
            for col in VECTOR_COLUMNS:
                if col in df.columns:
                    df[col] = df[col].map(lambda v: [float(x) for x in v.split()]
                                          if isinstance(v, str) and v else None)
            return df
        df = pd.read_parquet(result)
    except Exception as exc:
        raise RecordingError(result, f"cannot read the frames table ({exc})") from exc
    for col in LIST_COLUMNS:
        if col in df.columns:
            df[col] = df[col].map(lambda v: [] if v is None else list(v))
    return df


def read_manifest(result: Path) -> dict[str, Any]:
    path = Path(result) / "manifest.json" if Path(result).is_dir() else Path(result)
    if not path.exists():
        return {}
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise RecordingError(path, f"not valid JSON ({exc})") from exc
    return data if isinstance(data, dict) else {}
