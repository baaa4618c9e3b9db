#!/usr/bin/env bash
# Idempotent setup: .venv with every dependency, magtune_core installed editable, ros2_ws built.
# Re-runs are cheap: each step is skipped while its inputs are unchanged.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
venv="$root/.venv"
py=${PYTHON:-python3}

if [ ! -x "$venv/bin/python" ]; then
  if ! "$py" -m venv "$venv" 2>/dev/null; then
    echo "bootstrap: '$py -m venv' failed; installing python3-venv (needs root/sudo)" >&2
    if [ "$(id -u)" = 0 ]; then apt-get update -qq && apt-get install -y -qq python3-venv >/dev/null
    else sudo apt-get update -qq && sudo apt-get install -y -qq python3-venv >/dev/null; fi
    rm -rf "$venv"; "$py" -m venv "$venv"
  fi
fi

# A C compiler: the suite compiles the exported flight header (tests/cli/test_export.py, which fails
# without one). Debian's gcc (it provides cc) where a machine lacks one.
if ! command -v cc >/dev/null 2>&1; then
  echo "bootstrap: no C compiler (cc); installing Debian's gcc (needs root/sudo)" >&2
  if [ "$(id -u)" = 0 ]; then apt-get update -qq && apt-get install -y -qq gcc libc6-dev >/dev/null
  else sudo apt-get update -qq && sudo apt-get install -y -qq gcc libc6-dev >/dev/null; fi
fi

stamp="$venv/.magtune-deps"
want=$(cat "$root/scripts/requirements.txt" "$root/pyproject.toml" | sha1sum | cut -d' ' -f1)
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  echo "bootstrap: installing Python dependencies into .venv (about a minute on a new machine)" >&2
  quiet() { grep -v "is ignored: it is neither a file nor a directory" >&2 || true; }
  "$venv/bin/python" -m pip install -q --disable-pip-version-check -r "$root/scripts/requirements.txt" 2> >(quiet)
  "$venv/bin/python" -m pip install -q --disable-pip-version-check --no-deps -e "$root" 2> >(quiet)
  echo "$want" > "$stamp"
fi

# Build the ROS 2 workspace when its sources changed.
if [ -d "$root/ros2_ws/src" ] && [ -n "$(ls -A "$root/ros2_ws/src" 2>/dev/null)" ]; then
  wstamp="$root/ros2_ws/install/.magtune-src"
  wwant=$(cd "$root/ros2_ws/src" && find . -type f -not -path '*/__pycache__/*' -print0 | sort -z | xargs -0 sha1sum | sha1sum | cut -d' ' -f1)
  if [ "$(cat "$wstamp" 2>/dev/null)" != "$wwant" ]; then
    echo "bootstrap: colcon build of ros2_ws" >&2
    # ament_cmake packages (the interface packages tf2_msgs, rosbag2_interfaces) find the
    # wheels' CMake configs through AMENT_PREFIX_PATH/CMAKE_PREFIX_PATH = the venv
    (cd "$root/ros2_ws" && PATH="$venv/bin:$PATH" AMENT_PREFIX_PATH="$venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}" \
        CMAKE_PREFIX_PATH="$venv${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}" "$venv/bin/colcon" build \
        --event-handlers console_cohesion- summary- console_stderr- >/dev/null \
        2> >(grep -v "doesn't contain any 'local_setup" >&2 || true)) \
      || { echo "bootstrap: colcon build failed; see ros2_ws/log/latest_build" >&2; exit 1; }
    echo "$wwant" > "$wstamp"
  fi
fi

# Compile the numba code of the H-infinity norm (kernel, level model) once per change of its source (~70 s on a new
# machine; cached in magtune_core/ltp/__pycache__): the first J(K) of a run does not pay it.
kstamp="$venv/.magtune-kernel"
kwant=$(cat "$root"/magtune_core/ltp/{hinf_kernel,hinf_levels,expm,small_linalg}.py | sha1sum | cut -d' ' -f1)
if [ "$(cat "$kstamp" 2>/dev/null)" != "$kwant" ] || ! ls "$root"/magtune_core/ltp/__pycache__/hinf_kernel.*.nbi >/dev/null 2>&1; then
  echo "bootstrap: compiling the H-infinity kernel and level model (numba, about a minute on a new machine)" >&2
  # numba invalidates a cached function only when its own file changes; the kernel inlines
  # small_linalg and expm, so a change there must drop the whole cache
  rm -f "$root"/magtune_core/ltp/__pycache__/*.nbi "$root"/magtune_core/ltp/__pycache__/*.nbc
  (cd "$root" && "$venv/bin/python" -c "from magtune_core.ltp import hinf_kernel, hinf_levels; hinf_kernel.compile_all(); hinf_levels.compile_all()")
  echo "$kwant" > "$kstamp"
fi

# The hold certificate's kernel (design/hold_certificate.py), compiled once per change of its file (~8 s): a
# certificate's reported seconds are then its scan's
cstamp="$venv/.magtune-certificate"
cwant=$(sha1sum "$root"/magtune_core/design/hold_certificate.py | cut -d' ' -f1)
if [ "$(cat "$cstamp" 2>/dev/null)" != "$cwant" ]; then
  echo "bootstrap: compiling the hold certificate's kernel (numba)" >&2
  (cd "$root" && "$venv/bin/python" -c "from magtune_core.design import hold_certificate; hold_certificate.compile_all()")
  echo "$cwant" > "$cstamp"
fi
