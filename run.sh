#!/usr/bin/env bash
# Set everything up (first time only) and start lfstudio on the built-in simulated studio.
# Extra arguments go to the app, e.g. ./run.sh --screenshot window.png
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
source "$here/tools/setup-env.sh"
if [ -z "${DISPLAY:-}${WAYLAND_DISPLAY:-}" ] && [ -z "${QT_QPA_PLATFORM:-}" ]; then
  echo "No display found: starting lfstudio offscreen (nothing will appear on screen)."
  echo "Run it on a desktop, or under Xvfb, to see the window; ./run.sh --screenshot FILE.png saves a picture and exits."
  export QT_QPA_PLATFORM=offscreen
fi
exec "$LFSTUDIO_PY" -m lfstudio gui --simulated "$@"
