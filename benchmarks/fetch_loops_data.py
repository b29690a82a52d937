"""Fetch the public pose graphs listed in benchmarks/loops_data.json into benchmarks/data/loops/.

Each file comes from a pinned commit of a public repository (a shallow, blob-filtered git fetch
of that one commit, then `git show COMMIT:PATH`) and is checked against its sha256. The files
stay out of git (benchmarks/data/ is ignored).

    python benchmarks/fetch_loops_data.py [--out DIR]
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


def fetch(entry: dict[str, str], out: Path) -> Path:
    dst = out / entry["file"]
    if dst.exists() and hashlib.sha256(dst.read_bytes()).hexdigest() == entry["sha256"]:
        return dst
    with tempfile.TemporaryDirectory() as tmp:
        run = lambda *a: subprocess.run(["git", "-C", tmp, *a], check=True,  # noqa: E731
                                        capture_output=True)
        run("init", "-q")
        run("remote", "add", "origin", f"https://github.com/{entry['repo']}.git")
        run("fetch", "-q", "--depth", "1", "--filter=blob:none", "origin", entry["commit"])
        blob = subprocess.run(["git", "-C", tmp, "show", f"{entry['commit']}:{entry['path']}"],
                              check=True, capture_output=True).stdout
    digest = hashlib.sha256(blob).hexdigest()
    if digest != entry["sha256"]:
        raise SystemExit(f"{entry['repo']}:{entry['path']}: sha256 {digest}, expected "
                         f"{entry['sha256']}")
    dst.write_bytes(blob)
    return dst


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=HERE / "data" / "loops")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    for entry in json.loads((HERE / "loops_data.json").read_text())["graphs"]:
        path = fetch(entry, args.out)
        print(f"{entry['name']:<15} {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
