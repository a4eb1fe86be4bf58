#!/usr/bin/env bash
# Set everything up (first time only) and run the whole test suite, Qt offscreen.
# Extra arguments go to pytest, e.g. ./test.sh -k planner
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
source "$here/tools/setup-env.sh"
export QT_QPA_PLATFORM="${QT_QPA_PLATFORM:-offscreen}"
cd "$here"
# On every core and half as many again (pytest-xdist; tests marked xdist_group share one worker, in
# order): most tests spend their time waiting on simulated time and on subprocesses, so one worker per
# core left the CPUs a third idle (2 cores, 2 workers: 128 % CPU, 18 min 45 s; 3 workers: 155 %, 15 min).
# LFSTUDIO_TEST_WORKERS=N runs N workers; 0 runs them all in this process.
cores="$(nproc 2>/dev/null || echo 2)"
exec "$LFSTUDIO_PY" -m pytest -n "${LFSTUDIO_TEST_WORKERS:-$(( (3 * cores + 1) / 2 ))}" --dist loadgroup "$@"
