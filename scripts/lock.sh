#!/usr/bin/env bash
# Refresh requirements.lock, the pinned and hashed set every install uses (README, .ci/run).
#
#   scripts/lock.sh           re-resolve at the newest versions pyproject.toml allows, write the lock
#   scripts/lock.sh --check   resolve the newest allowed versions into a temporary file and print
#                             what would change against the lock; writes nothing, exit 1 if stale
#
# Then install the new lock (README, command 1) and run the tests before committing it. The
# lowest declared OpenCV is tested by .ci/run as well (FRONTDIAG_LOWEST_OPENCV in that script).
set -euo pipefail
cd "$(dirname "$0")/.."
uv=${UV:-.venv/bin/uv}
[ -x "$uv" ] || uv=$(command -v uv) || { echo "lock.sh: uv not found: run README command 1 first (uv is in the dev extra)" >&2; exit 2; }

compile() {  # $1: output file
  "$uv" pip compile pyproject.toml --all-extras --universal --python-version 3.11 \
    --generate-hashes --upgrade --quiet --custom-compile-command "scripts/lock.sh" -o "$1"
}

if [ "${1:-}" = "--check" ]; then
  tmp=$(mktemp)
  trap 'rm -f "$tmp"' EXIT
  compile "$tmp"
  pins() { grep -E '^[A-Za-z0-9_.-]+==' "$1" | sed 's/ \\$//' | sort; }
  if diff <(pins requirements.lock) <(pins "$tmp"); then
    echo "requirements.lock is current: every pin is the newest version pyproject.toml allows."
  else
    echo "requirements.lock is behind (< locked, > newest allowed): run scripts/lock.sh to refresh." >&2
    exit 1
  fi
else
  compile requirements.lock
  echo "wrote requirements.lock: install it (README, command 1) and run the tests before committing"
fi
