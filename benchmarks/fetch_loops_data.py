"""Fetch the public pose graphs listed in benchmarks/loops_data.json into benchmarks/data/loops/.

Also the held-out graphs of benchmarks/loops_heldout.json and their ground-truth poses (for
benchmarks/bench_loops_gt.py).

Each file comes from a pinned commit of a public repository (a shallow, blob-filtered git fetch
of that one commit, then `git show COMMIT:PATH`) and is checked against its sha256. The files
stay out of git (benchmarks/data/ is ignored).

    python benchmarks/fetch_loops_data.py [--out DIR] [--local DIR]

Without network access, point --local at a folder holding clones (or bare snapshots) of the
listed repositories; each is looked up as DIR/OWNER+NAME[/repo], DIR/OWNER/NAME or DIR/NAME, and
the pinned commit is read from it with `git show`.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _local_git(root: Path, repo: str) -> Path | None:
    owner, name = repo.split("/")
    for cand in (root / f"{owner}+{name}" / "repo", root / f"{owner}+{name}",
                 root / owner / name, root / name):
        if cand.is_dir():
            return cand
    return None


def _show(git_dir: Path, entry: dict[str, str]) -> bytes:
    return subprocess.run(["git", "-C", str(git_dir), "show", f"{entry['commit']}:{entry['path']}"],
                          check=True, capture_output=True).stdout


def fetch(entry: dict[str, str], out: Path, local: Path | None = None) -> Path:
    dst = out / entry["file"]
    if dst.exists() and hashlib.sha256(dst.read_bytes()).hexdigest() == entry["sha256"]:
        return dst
    git_dir = _local_git(local, entry["repo"]) if local else None
    if local and git_dir is None:
        raise SystemExit(f"{entry['repo']}: no clone under {local} "
                         f"(looked for OWNER+NAME, OWNER/NAME and NAME)")
    try:
        blob = _show(git_dir, entry) if git_dir else _fetch_remote(entry)
    except subprocess.CalledProcessError as exc:
        err = exc.stderr.decode(errors="replace").strip().splitlines()
        raise SystemExit(f"{entry['repo']}@{entry['commit'][:10]}:{entry['path']}: "
                         f"{err[-1] if err else exc} (offline? use --local DIR with a clone)") from None
    digest = hashlib.sha256(blob).hexdigest()
    if digest != entry["sha256"]:
        raise SystemExit(f"{entry['repo']}:{entry['path']}: sha256 {digest}, expected "
                         f"{entry['sha256']}")
    dst.write_bytes(blob)
    return dst


def _fetch_remote(entry: dict[str, str]) -> bytes:
    with tempfile.TemporaryDirectory() as tmp:
        run = lambda *a: subprocess.run(["git", "-C", tmp, *a], check=True,  # noqa: E731
                                        capture_output=True)
        run("init", "-q")
        run("remote", "add", "origin", f"https://github.com/{entry['repo']}.git")
        run("fetch", "-q", "--depth", "1", "--filter=blob:none", "origin", entry["commit"])
        return _show(Path(tmp), entry)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=HERE / "data" / "loops")
    ap.add_argument("--local", type=Path, default=None,
                    help="folder of local clones to read the pinned commits from (no network)")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    for entry in json.loads((HERE / "loops_data.json").read_text())["graphs"]:
        path = fetch(entry, args.out, args.local)
        print(f"{entry['name']:<15} {path}")
    for held in json.loads((HERE / "loops_heldout.json").read_text())["graphs"]:
        for part in ("graph", "ground_truth"):
            path = fetch(held[part], args.out, args.local)
            print(f"{held['name']:<15} {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
