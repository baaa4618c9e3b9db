#!/usr/bin/env bash
# The suite on a busy machine (issue 60): BUSY CPU hogs (`yes > /dev/null`, default 2) run beside pytest,
# the whole run repeated RUNS times (default 1); each run prints its time and the 1-min load average.
#   bash scripts/load_test.sh                    # tests/ros with 2 hogs, once
#   BUSY=2 RUNS=3 bash scripts/load_test.sh tests/ros tests/cli
# The hogs are this script's children, killed on any exit (trap); pytest gets the arguments of scripts/test.sh.
# Each run's test directories stay in LOAD_DIR/run<r> (default: a new directory under /tmp); after each run the
# mode managers' bring-up times found there are summarized (per node and transition: count, median, max).
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
busy=${BUSY:-2}; runs=${RUNS:-1}; out=${LOAD_DIR:-$(mktemp -d /tmp/magtune-load.XXXXXX)}; mkdir -p "$out"
[ "$#" -gt 0 ] || set -- tests/ros
cd "$root"
. scripts/env.sh
hogs=()
stop_hogs() { for p in "${hogs[@]}"; do kill "$p" 2>/dev/null || true; done; }
trap stop_hogs EXIT INT TERM
for _ in $(seq "$busy"); do yes > /dev/null & hogs+=($!); done
workers=$(nproc 2>/dev/null || echo 2); [ "$workers" -gt 4 ] && workers=4
status=0
for r in $(seq "$runs"); do
  t0=$(date +%s)
  set +e
  python -m pytest -q -ra --durations=10 -n "$workers" --dist loadfile -p no:cacheprovider \
    --basetemp "$out/run$r" "$@"
  rc=$?
  set -e
  python - "$out/run$r" <<'PY' >&2
import pathlib, re, statistics, sys
times = {}
for log in pathlib.Path(sys.argv[1]).rglob("mode_manager.log"):
    for m in re.finditer(r"\]: (\w+): (inactive|active) after ([0-9.]+) s", log.read_text(errors="replace")):
        times.setdefault((m[1], "configure" if m[2] == "inactive" else "activate"), []).append(float(m[3]))
for (node, what), ts in sorted(times.items()):
    print(f"load_test: bring-up {node} {what}: {len(ts)} times, median {statistics.median(ts):.2f} s, max {max(ts):.2f} s")
PY
  echo "load_test: run $r/$runs: exit $rc in $(( $(date +%s) - t0 )) s with $busy busy processes; load average $(cut -d' ' -f1-3 /proc/loadavg)" >&2
  [ "$rc" -eq 0 ] || status=$rc
done
exit "$status"
