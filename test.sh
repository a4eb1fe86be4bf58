#!/usr/bin/env bash
# Set everything up (first time only) and run the whole test suite, Qt offscreen.
# Extra arguments go to pytest, e.g. ./test.sh -k planner
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
source "$here/tools/setup-env.sh"
export QT_QPA_PLATFORM="${QT_QPA_PLATFORM:-offscreen}"
cd "$here"
# On every core (pytest-xdist; tests marked xdist_group share one worker, in order);
# LFSTUDIO_TEST_WORKERS=0 runs them all in this process.
exec "$LFSTUDIO_PY" -m pytest -n "${LFSTUDIO_TEST_WORKERS:-auto}" --dist loadgroup "$@"
