#!/usr/bin/env bash
# The test command of the README: bootstrap (idempotent), lint (ruff), then the whole pytest suite.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
bash "$root/scripts/bootstrap.sh"
cd "$root"
. scripts/env.sh
echo "ruff check:" >&2
ruff check .
# one pytest worker per core, at most 4 (xdist; tests/conftest.py: the node tests one at a time on one worker,
# every other module on any); `bash scripts/test.sh -n 0` runs in one process
workers=$(nproc 2>/dev/null || echo 2); [ "$workers" -gt 4 ] && workers=4
exec python -m pytest -q -ra --durations=20 -n "$workers" --dist loadfile "$@"
