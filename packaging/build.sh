#!/usr/bin/env bash
# Build the one-folder bundle dist/lfstudio/ (a studio workstation needs no Python to run it):
#   packaging/build.sh
# Uses ./.venv (created and filled by tools/setup-env.sh, as run.sh does; LFSTUDIO_VENV moves it),
# installs PyInstaller into it and runs packaging/lfstudio.spec. Takes a few minutes; the bundle is
# about 600 MB. Run it on the oldest Linux you want to support (the bundle needs that glibc or newer).
set -euo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
source "$here/tools/setup-env.sh"
"$LFSTUDIO_PY" -m pip install --disable-pip-version-check -q "pyinstaller>=6.5"
cd "$here"
"$LFSTUDIO_PY" -m PyInstaller --noconfirm --clean --log-level WARN \
  --distpath "$here/dist" --workpath "$here/build/pyinstaller" packaging/lfstudio.spec
echo "bundle: $here/dist/lfstudio/lfstudio ($(du -sh "$here/dist/lfstudio" | cut -f1))"
