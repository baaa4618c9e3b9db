#!/usr/bin/env bash
# The test command of the README: bootstrap (idempotent), lint (ruff), then the whole pytest suite.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
bash "$root/scripts/bootstrap.sh"
cd "$root"
. scripts/env.sh
echo "ruff check:" >&2
ruff check .
exec python -m pytest -q -ra --durations=20 "$@"
