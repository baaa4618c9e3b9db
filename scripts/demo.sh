#!/usr/bin/env bash
# The README's main command: bootstrap (idempotent), then the demo of what magtune does.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
bash "$root/scripts/bootstrap.sh"
cd "$root"
. scripts/env.sh
echo "== Table 1: the paper's tuned controllers vs ours (shipped gains, recomputed) =="
magtune table1
