"""Rebuild the real-data validation recordings from the fetched public repositories.

    python validation/build.py                          # every recording, into /work/valdata
    python validation/build.py --out DIR --src DIR      # other places
    python validation/build.py --only euroc_still_cam0 kitti06_start
    python validation/build.py --hash                   # fill missing sha256 in the manifest

Nothing here is committed data: ``validation/manifest.json`` names, for every recording, the
public repository and commit its images come from, every source path with its sha256, the
licence, the camera and the labels (frame-index intervals, written by hand from contact sheets).
This script reads those files, checks their sha256, and writes each recording into a real
container (ROS 1 bag, ROS 2 bag with sqlite3 or MCAP storage, plain MCAP) with its
``<recording>.labels.csv`` beside it, under ``OUT/<split>/``.

Sources are looked up under ``--src`` (default ``/work/.mirror``) as ``owner+name/`` holding
either the repository's files (a plain checkout or download) or a bare git directory ``repo``
(what the ``fetch`` tool brings; a checkout ``repo/.git`` works too), read with
``git show COMMIT:PATH``.
"""

from __future__ import annotations

import argparse
import hashlib
import itertools
import json
import subprocess
import sys
import tempfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from decimal import Decimal
from pathlib import Path
from typing import Any

import cv2
import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE.parent) not in sys.path:
    sys.path.insert(0, str(HERE.parent))

from frontdiag.conditions import LABELS  # noqa: E402
from frontdiag.errors import ConfigError  # noqa: E402
from frontdiag.io.writer import (  # noqa: E402
    RecordingWriter,
    camera_info_msg,
    compressed_image_msg,
    image_msg,
)

MANIFEST = HERE / "manifest.json"
DEFAULT_SRC = Path("/work/.mirror")
DEFAULT_OUT = Path("/work/valdata")
SPLITS = ("dev", "report")
CONTAINER_SUFFIX = {"bag": ".bag", "mcap": ".mcap", "mcap-ros1": ".mcap", "ros2-db3": "",
                    "ros2-mcap": ""}
ENCODINGS = ("mono8", "bgr8", "source", "jpeg")


# -- manifest ------------------------------------------------------------------------------

def load_manifest(path: Path = MANIFEST) -> dict[str, Any]:
    """Read the manifest and check what the build relies on (one line per fault)."""
    try:
        m = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read the manifest ({exc})") from exc
    sources = m.get("sources", {})
    names: set[str] = set()
    for i, rec in enumerate(m.get("recordings", [])):
        where = f"{path}: recordings[{i}]"
        for key in ("name", "source", "split", "container", "frames", "stamps", "labels",
                    "camera"):
            if key not in rec:
                raise ConfigError(f"{where}: missing field {key!r}")
        if rec["name"] in names:
            raise ConfigError(f"{where}: duplicate name {rec['name']!r}")
        names.add(rec["name"])
        for key in (rec["source"], rec["stamps"].get("source", rec["source"])):
            if key not in sources:
                raise ConfigError(f"{where}: unknown source {key!r}")
        if rec["split"] not in SPLITS:
            raise ConfigError(f"{where}: split must be one of {', '.join(SPLITS)}")
        if rec["container"] not in CONTAINER_SUFFIX:
            raise ConfigError(f"{where}: unknown container {rec['container']!r}")
        if rec.get("encoding", "mono8") not in ENCODINGS:
            raise ConfigError(f"{where}: unknown encoding {rec.get('encoding')!r}")
        n = expected_frames(rec)
        for a, b, cond in rec["labels"]:
            if cond not in LABELS:
                raise ConfigError(f"{where}: unknown condition {cond!r}")
            if not (0 <= int(a) <= int(b)) or (n is not None and int(b) >= n):
                raise ConfigError(f"{where}: label interval [{a}, {b}] outside 0..{n}")
    return m


def expected_frames(rec: dict[str, Any]) -> int | None:
    fr = rec["frames"]
    if fr.get("kind") == "video":
        return int(fr["count"])
    return len(fr["files"])


# -- reading sources -----------------------------------------------------------------------

@dataclass
class Source:
    """One public repository at one commit, found under the source root."""

    repo: str
    commit: str
    root: Path

    @property
    def base(self) -> Path:
        return self.root / self.repo.replace("/", "+")

    def read(self, path: str) -> bytes:
        plain = self.base / path
        if plain.is_file():
            return plain.read_bytes()
        gitdir = self.base / "repo"
        if (gitdir / ".git").is_dir():  # a checkout rather than a bare git directory
            gitdir = gitdir / ".git"
        if gitdir.is_dir():
            r = subprocess.run(["git", "--git-dir", str(gitdir), "show", f"{self.commit}:{path}"],
                               capture_output=True, check=False)
            if r.returncode == 0:
                return r.stdout
            raise ConfigError(f"{self.repo}@{self.commit[:12]}: cannot read {path} "
                              f"({r.stderr.decode(errors='replace').strip()})")
        raise ConfigError(f"source {self.repo} not found under {self.root}",
                          hint=f"fetch github:{self.repo} (commit {self.commit}) or pass --src")


def aid_source(name: str, doc: str) -> tuple[dict[str, Any], Source]:
    """For a labelling aid's command line: the manifest entry of recording ``name`` and its
    source, found under ``--src`` (default /work/.mirror)."""
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("--src", type=Path, default=DEFAULT_SRC)
    a = ap.parse_args()
    m = load_manifest(MANIFEST)
    rec = next(r for r in m["recordings"] if r["name"] == name)
    s = m["sources"][rec["source"]]
    return rec, Source(s["repo"], s["commit"], a.src)


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def checked(src: Source, entry: dict[str, Any]) -> bytes:
    data = src.read(entry["path"])
    want = entry.get("sha256")
    if want and sha256(data) != want:
        raise ConfigError(f"{src.repo}:{entry['path']}: sha256 {sha256(data)[:16]}… "
                          f"differs from the manifest's {want[:16]}…",
                          hint="the source changed; check the commit in the manifest")
    return data


def decode(data: bytes, where: str) -> np.ndarray:
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ConfigError(f"{where}: not a decodable image")
    if img.ndim == 3 and img.shape[2] == 4:  # an alpha channel carries no image content
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    return img


def frames_of(rec: dict[str, Any], src: Source) -> Iterator[tuple[bytes, np.ndarray, str]]:
    """(original bytes or b'', decoded image, where) per frame, in recording order."""
    fr = rec["frames"]
    if fr.get("kind") == "video":
        data = checked(src, fr)
        with tempfile.NamedTemporaryFile(suffix=Path(fr["path"]).suffix) as tmp:
            tmp.write(data)
            tmp.flush()
            cap = cv2.VideoCapture(tmp.name)
            start, step, count = int(fr.get("start", 0)), int(fr.get("step", 1)), int(fr["count"])
            idx = got = 0
            while got < count:
                ok, img = cap.read()
                if not ok:
                    raise ConfigError(f"{src.repo}:{fr['path']}: video ends at frame {idx}, "
                                      f"{count} wanted from {start} every {step}")
                if idx >= start and (idx - start) % step == 0:
                    got += 1
                    yield b"", img, f"{fr['path']}#{idx}"
                idx += 1
            cap.release()
        return
    for entry in fr["files"]:
        data = checked(src, entry)
        yield data, decode(data, f"{src.repo}:{entry['path']}"), entry["path"]


def stamps_of(rec: dict[str, Any], src: Source, n: int,
              stamp_src: Source | None = None) -> list[int]:
    """Header stamps (ns) of the n frames: the recording's own where known, else nominal."""
    st = rec["stamps"]
    kind = st["kind"]
    if kind == "rate":
        t0 = int(st["t0_ns"])
        return [t0 + round(i * 1e9 / float(st["hz"])) for i in range(n)]
    if kind == "filename_seconds":
        files = rec["frames"]["files"]
        return [int(Decimal(Path(e["path"]).stem) * 1_000_000_000) for e in files]
    if kind == "filename_ns":
        return [int(Path(e["path"]).stem) for e in rec["frames"]["files"]]
    if kind == "filename_us":
        return [int(Path(e["path"]).stem) * 1000 for e in rec["frames"]["files"]]
    if kind == "times_txt":
        lines = checked(stamp_src or src, st).decode().split()
        first = int(st.get("first", 0))
        t0 = int(st["t0_ns"])
        return [t0 + round(float(v) * 1e9) for v in lines[first:first + n]]
    raise ConfigError(f"{rec['name']}: unknown stamps kind {kind!r}")


# -- writing -------------------------------------------------------------------------------

def intrinsics(cam: dict[str, Any]) -> tuple[np.ndarray, np.ndarray | None, str]:
    fx, fy, cx, cy = (float(cam[k]) for k in ("fx", "fy", "cx", "cy"))
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    D = np.asarray(cam["D"], float) if cam.get("D") else None
    return K, D, str(cam.get("distortion_model", "plumb_bob"))


def output_path(out: Path, rec: dict[str, Any]) -> Path:
    return out / rec["split"] / (rec["name"] + CONTAINER_SUFFIX[rec["container"]])


def labels_csv(rec: dict[str, Any], stamps: Sequence[int]) -> str:
    """The ``t_start_ns,t_end_ns,condition`` text of a recording's frame-index labels."""
    lines = ["t_start_ns,t_end_ns,condition"]
    for a, b, cond in rec["labels"]:
        if int(b) >= len(stamps):
            raise ConfigError(f"{rec['name']}: label [{a}, {b}] past the last frame "
                              f"({len(stamps) - 1})")
        lines.append(f"{stamps[int(a)]},{stamps[int(b)]},{cond}")
    return "\n".join(lines) + "\n"


def _source(sources: dict[str, Any], key: str, root: Path) -> Source:
    return Source(sources[key]["repo"], sources[key]["commit"], root)


def build_one(rec: dict[str, Any], sources: dict[str, Any], src_root: Path,
              out: Path) -> tuple[Path, int]:
    """Write one recording and its labels; return (path, frames)."""
    src = _source(sources, rec["source"], src_root)
    frames = list(frames_of(rec, src))
    st_key = rec["stamps"].get("source")
    stamps = stamps_of(rec, src, len(frames),
                       _source(sources, st_key, src_root) if st_key else None)
    if len(stamps) != len(frames):
        raise ConfigError(f"{rec['name']}: {len(frames)} frames but {len(stamps)} stamps")
    if any(b <= a for a, b in itertools.pairwise(stamps)):
        raise ConfigError(f"{rec['name']}: frame stamps are not increasing")
    path = output_path(out, rec)
    path.parent.mkdir(parents=True, exist_ok=True)
    _remove(path)
    K, D, model = intrinsics(rec["camera"])
    enc = rec.get("encoding", "mono8")
    ns = rec.get("topic_ns", "/camera")
    frame_id = ns.strip("/").replace("/", "_") + "_optical"
    with RecordingWriter(path, rec["container"]) as w:
        for (raw, img, where), t in zip(frames, stamps, strict=True):
            h, wd = img.shape[:2]
            if enc == "source" and raw:
                fmt = "png" if raw[:4] == b"\x89PNG" else "jpeg"
                w.write(f"{ns}/image_raw/compressed", "sensor_msgs/msg/CompressedImage",
                        compressed_image_msg(raw, fmt, t, frame_id), t)
            elif enc in ("jpeg", "source"):
                ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 95])
                if not ok:
                    raise ConfigError(f"{where}: cannot encode as JPEG")
                w.write(f"{ns}/image_raw/compressed", "sensor_msgs/msg/CompressedImage",
                        compressed_image_msg(buf.tobytes(), "jpeg", t, frame_id), t)
            else:
                arr = img
                if img.ndim == 3 and enc == "mono8":
                    arr = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
                elif img.ndim == 2 and enc == "bgr8":
                    arr = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
                w.write(f"{ns}/image_raw", "sensor_msgs/msg/Image",
                        image_msg(arr, enc, t, frame_id), t)
            w.write(f"{ns}/camera_info", "sensor_msgs/msg/CameraInfo",
                    camera_info_msg(K, wd, h, t, D=D, model=model, frame_id=frame_id), t)
    labels_file = path.parent / (rec["name"] + CONTAINER_SUFFIX[rec["container"]]
                                 + ".labels.csv")
    if rec["container"] in ("ros2-db3", "ros2-mcap"):
        labels_file = path.parent / (rec["name"] + ".labels.csv")
    labels_file.write_text(labels_csv(rec, stamps))
    return path, len(frames)


def _remove(path: Path) -> None:
    if path.is_dir():
        for p in sorted(path.rglob("*"), reverse=True):
            p.unlink() if p.is_file() else p.rmdir()
        path.rmdir()
    elif path.exists():
        path.unlink()


def recording_digest(path: Path) -> str:
    """sha256 of a built recording (a bag folder: of its files' digests in name order)."""
    if path.is_dir():
        h = hashlib.sha256()
        for p in sorted(path.iterdir()):
            if p.name != "metadata.yaml":  # holds the writer's wall-clock-free summary only
                h.update(p.name.encode() + sha256(p.read_bytes()).encode())
        return h.hexdigest()
    return sha256(path.read_bytes())


def fill_hashes(m: dict[str, Any], src_root: Path) -> int:
    """Put the sha256 of every source file that has none yet into the manifest (in memory)."""
    n = 0
    for rec in m["recordings"]:
        src = _source(m["sources"], rec["source"], src_root)
        entries = [rec["frames"]] if rec["frames"].get("kind") == "video" \
            else list(rec["frames"]["files"])
        for e in entries:
            if not e.get("sha256"):
                e["sha256"] = sha256(src.read(e["path"]))
                n += 1
        st = rec["stamps"]
        if "path" in st and not st.get("sha256"):
            st["sha256"] = sha256(_source(m["sources"], st.get("source", rec["source"]),
                                          src_root).read(st["path"]))
            n += 1
    return n


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="validation/build.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--src", type=Path, default=DEFAULT_SRC,
                    help="where the fetched repositories are (default /work/.mirror)")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT,
                    help="where to write the recordings (default /work/valdata)")
    ap.add_argument("--manifest", type=Path, default=MANIFEST)
    ap.add_argument("--only", nargs="*", default=None, help="recording names to build")
    ap.add_argument("--hash", action="store_true",
                    help="fill missing source sha256 values in the manifest, build nothing")
    ap.add_argument("--record", action="store_true",
                    help="after building, store each built recording's sha256 in the manifest")
    a = ap.parse_args(argv)
    m = load_manifest(a.manifest)
    if a.hash:
        n = fill_hashes(m, a.src)
        a.manifest.write_text(json.dumps(m, indent=1) + "\n")
        print(f"{n} sha256 values added to {a.manifest}")
        return 0
    try:
        a.out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"cannot write to --out {a.out} ({exc.strerror})",
                          hint="choose a writable directory") from exc
    wanted = set(a.only) if a.only else None
    unknown = (wanted or set()) - {r["name"] for r in m["recordings"]}
    if unknown:
        raise ConfigError(f"unknown recording(s): {', '.join(sorted(unknown))}")
    changed = False
    for rec in m["recordings"]:
        if wanted is not None and rec["name"] not in wanted:
            continue
        path, n = build_one(rec, m["sources"], a.src, a.out)
        digest = recording_digest(path)
        note = ""
        if a.record:
            changed |= rec.get("sha256") != digest
            rec["sha256"] = digest
        elif rec.get("sha256") and rec["sha256"] != digest:
            note = "  (differs from the manifest's sha256: other writer library versions?)"
        print(f"{rec['split']:6s} {path}  {n} frames  sha256 {digest[:12]}{note}")
    if changed:
        a.manifest.write_text(json.dumps(m, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    from frontdiag.errors import FrontdiagError

    try:
        raise SystemExit(main())
    except FrontdiagError as exc:
        hint = f" ({exc.hint})" if exc.hint else ""
        print(f"build.py: {exc}{hint}", file=sys.stderr)
        raise SystemExit(2) from None
