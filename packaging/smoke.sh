#!/usr/bin/env bash
# Smoke check of the packaging (not part of the test suite; takes several minutes):
#   packaging/smoke.sh              # build the bundle, run it, then pip- and pipx-install a checkout
#   SMOKE_SKIP_BUILD=1 packaging/smoke.sh   # reuse dist/lfstudio
#   SMOKE_SKIP_INSTALL=1 packaging/smoke.sh # bundle only
# The bundle runs with a stripped environment (no PYTHONPATH, no venv on PATH, fresh HOME):
#   --version; doctor (versions, RAW decoding, HEVC encoding, lens database, resources, simulated rig);
#   the GUI offscreen on the simulated studio for a few seconds (--screenshot); a small virtual-studio
#   DNG dataset processed by worker processes; the log file written.
# Then `pip install .` and `pipx install .` into throwaway folders: `lfstudio --version` and
# `lfstudio doctor` (resources found outside the checkout). Prints PASS/FAIL per step and the bundle size.
set -uo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
tmp="$(mktemp -d /tmp/lfstudio-smoke.XXXXXX)"
bundle="$here/dist/lfstudio/lfstudio"
failures=0
step() {  # step NAME COMMAND... : run, report PASS/FAIL with the last lines of output on failure
  local name="$1"; shift
  local out="$tmp/step-$(echo "$name" | tr -c 'a-zA-Z0-9' '_').log"
  local t0=$SECONDS
  if "$@" >"$out" 2>&1; then
    echo "PASS  $name ($((SECONDS - t0)) s)"
  else
    echo "FAIL  $name ($((SECONDS - t0)) s): last lines of $out:"; tail -n 15 "$out" | sed 's/^/      /'
    failures=$((failures + 1))
  fi
}
# the bundle must not lean on this machine's Python set-up
clean_env=(env -i "HOME=$tmp/home" "PATH=/usr/local/bin:/usr/bin:/bin" "QT_QPA_PLATFORM=offscreen"
           "LFSTUDIO_LOG_DIR=$tmp/logs" "LFSTUDIO_CONFIG_DIR=$tmp/config" "LANG=C.UTF-8")
mkdir -p "$tmp/home"

if [ -z "${SMOKE_SKIP_BUILD:-}" ] || [ ! -x "$bundle" ]; then
  step "build bundle (packaging/build.sh)" "$here/packaging/build.sh"
fi
if [ ! -x "$bundle" ]; then echo "FAIL  no bundle at $bundle"; exit 1; fi

version_ok() { "${clean_env[@]}" "$bundle" --version | tee /dev/stderr | grep -qx "lfstudio [0-9][0-9.]*"; }
step "bundle: lfstudio --version" version_ok
step "bundle: lfstudio doctor" "${clean_env[@]}" "$bundle" doctor
gui_ok() {
  rm -f "$tmp/window.png"
  "${clean_env[@]}" timeout 120 "$bundle" gui --screenshot "$tmp/window.png" || return 1
  [ "$(stat -c %s "$tmp/window.png" 2>/dev/null || echo 0)" -gt 20000 ]
}
step "bundle: GUI offscreen on the simulated studio, screenshot written" gui_ok
pipeline_ok() {
  "${clean_env[@]}" "$bundle" virtual-dataset "$tmp/ds" --grid 3x2 --width 480 --format dng --workers 1 &&
  "${clean_env[@]}" timeout 300 "$bundle" calibrate "$tmp/ds" &&
  "${clean_env[@]}" timeout 300 "$bundle" process "$tmp/ds" --workers 2 &&
  [ "$(ls "$tmp/ds/processed" | wc -l)" -eq 6 ]
}
step "bundle: DNG dataset rendered, calibrated (OpenCV SIFT) and processed by 2 worker processes (rawpy)" pipeline_ok
log_ok() { grep -q "lfstudio.rig.grbl: .* > b'\$H" "$tmp/logs/lfstudio.log" && grep -q "processing of .* finished" "$tmp/logs/lfstudio.log" &&
          grep -q "calibration of .* finished" "$tmp/logs/lfstudio.log"; }
step "bundle: log file with device traffic and milestones" log_ok

if [ -z "${SMOKE_SKIP_INSTALL:-}" ]; then
  py="$(command -v python3.11 || command -v python3)"
  pip_ok() {
    "$py" -m venv "$tmp/pipvenv" && "$tmp/pipvenv/bin/pip" install -q --disable-pip-version-check "$here" &&
    cd "$tmp" && "${clean_env[@]}" "$tmp/pipvenv/bin/lfstudio" --version &&
    "${clean_env[@]}" "$tmp/pipvenv/bin/lfstudio" doctor --quick &&
    "${clean_env[@]}" "$tmp/pipvenv/bin/python" -c \
      "from lfstudio.resources import RESOURCES_DIR as r; print(r); assert r.is_relative_to('$tmp/pipvenv') and (r / 'presets/rigs.toml').is_file() and (r / 'icons/lfstudio.svg').is_file()" &&
    "${clean_env[@]}" "$tmp/pipvenv/bin/lfstudio" doctor
  }
  step "pip install . (non-editable, fresh venv): lfstudio --version, doctor, resources" pip_ok
  pipx_ok() {
    "$py" -m venv "$tmp/pipxtool" && "$tmp/pipxtool/bin/pip" install -q --disable-pip-version-check pipx &&
    PIPX_HOME="$tmp/pipx" PIPX_BIN_DIR="$tmp/pipx-bin" PIPX_MAN_DIR="$tmp/pipx-man" \
      "$tmp/pipxtool/bin/pipx" install "$here" &&
    cd "$tmp" && "${clean_env[@]}" "$tmp/pipx-bin/lfstudio" --version &&
    "${clean_env[@]}" "$tmp/pipx-bin/lfstudio" doctor
  }
  step "pipx install . : lfstudio --version, doctor" pipx_ok
fi

size="$(du -sh "$here/dist/lfstudio" | cut -f1)"
files="$(find "$here/dist/lfstudio" -type f | wc -l)"
echo "bundle size: $size ($files files) in $here/dist/lfstudio"
[ -f "$tmp/window.png" ] && echo "screenshot: $tmp/window.png"
if [ "$failures" -eq 0 ]; then echo "smoke: PASS"; else echo "smoke: FAIL ($failures step(s))"; fi
exit $((failures > 0))
