#!/usr/bin/env bash
# The paper's simulation study (section 5, Figs. 2-5): SIL runs of the shipped gains for
# sigma = 60, 120, 240 over ORBITS orbits (default 5), each recorded to bags/sigma_S_<N>orbits,
# then `magtune report` overlays them in reports/paper/. About 1-2 minutes per run.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
bash "$root/scripts/bootstrap.sh"
cd "$root"
. scripts/env.sh
orbits=${ORBITS:-5}
bags=()
for s in 60 120 240; do
  bag="bags/sigma_${s}_${orbits}orbits"
  rm -rf "$bag"
  echo "== SIL sigma = $s, $orbits orbits -> $bag =="
  magtune sil --gains "config/gains/sigma_${s}.yaml" --orbits "$orbits" --ts 1 --bag "$bag"
  bags+=("$bag")
done
magtune report "${bags[@]}" --out reports/paper
echo "figures and summary: reports/paper/"
