#!/usr/bin/env bash
# Build the documentation site (Sphinx, docs/) into docs/_build/html and open it in the browser.
#   tools/docs.sh            build (warnings are errors, as in the test suite) and open
#   tools/docs.sh --no-open  build only
# Sets up ./.venv first, as run.sh and test.sh do (the docs tools come with the test extra).
set -euo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
source "$here/tools/setup-env.sh"
out="$here/docs/_build/html"
"$LFSTUDIO_PY" -m sphinx -W --keep-going -q -b html "$here/docs" "$out"
echo "The site is in $out/index.html"
if [ "${1:-}" != "--no-open" ]; then
  "$LFSTUDIO_PY" -m webbrowser -t "file://$out/index.html" >/dev/null 2>&1 || true
fi
