#!/usr/bin/env bash
# Create or refresh ./.venv with lfstudio and its test tools. Sourced by run.sh and test.sh.
# Idempotent: re-installs only when pyproject.toml changed since the last install.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${LFSTUDIO_VENV:-$here/.venv}"

py="${PYTHON:-}"
if [ -z "$py" ]; then
  for cand in python3.13 python3.12 python3.11 python3; do
    if command -v "$cand" >/dev/null 2>&1 && "$cand" -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
      py="$cand"; break
    fi
  done
fi
if [ -z "$py" ]; then
  echo "lfstudio needs Python 3.11 or newer (python3.11 not found). Install it, or set PYTHON=/path/to/python3.11." >&2
  exit 1
fi

# Qt needs a few system libraries even offscreen; install them when we can (Debian/Ubuntu as root).
# The linker cache is read once into a variable and each library matched exactly ("<TAB>name (").
# Not `ldconfig -p | grep -q name`: under pipefail that reports a present library as missing
# whenever grep exits on its match before ldconfig has written the rest (ldconfig gets SIGPIPE).
ld_cache="$(ldconfig -p 2>/dev/null || /sbin/ldconfig -p 2>/dev/null || true)"
have_lib() { [[ $'\n'"$ld_cache" == *$'\n\t'"$1 ("* ]]; }
need_pkgs=()
if [ -n "$ld_cache" ]; then
  for lib in libEGL.so.1:libegl1 libGL.so.1:libgl1 libfontconfig.so.1:libfontconfig1 libxkbcommon.so.0:libxkbcommon0 libdbus-1.so.3:libdbus-1-3 libglib-2.0.so.0:libglib2.0-0; do
    so="${lib%%:*}"; pkg="${lib##*:}"
    if ! have_lib "$so"; then need_pkgs+=("$pkg"); fi
  done
fi

# apt_step "what it does" apt-get ARGS...: run one apt-get step quietly; on failure say which step
# failed and why (another package manager holding apt's lock, or apt's own last lines).
apt_step() {
  local what="$1"; shift
  local out rc=0
  echo "  $what: $*"
  out="$(DEBIAN_FRONTEND=noninteractive "$@" 2>&1)" || rc=$?
  [ "$rc" -eq 0 ] && return 0
  local lock
  lock="$(printf '%s\n' "$out" | sed -n 's/^E: \(Could not get lock .*\)$/\1/p; s/^E: \(Unable to acquire the dpkg frontend lock .*\)$/\1/p' | head -n 1)"
  if [ -n "$lock" ]; then
    echo "Could not install system libraries for Qt: '$*' ($what) failed because another package manager is running: $lock. Wait for it to finish, then run this again." >&2
  else
    echo "Could not install system libraries for Qt: '$*' ($what) failed with exit code $rc. apt-get said:" >&2
    printf '%s\n' "$out" | tail -n 8 | sed 's/^/    /' >&2
  fi
  return "$rc"
}
if [ "${#need_pkgs[@]}" -gt 0 ]; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "Qt needs system libraries that are missing: ${need_pkgs[*]}. Installing them with apt-get (running as root):"
    if ! { apt_step "refresh the package lists" apt-get update -qq \
           && apt_step "install" apt-get install -y -qq "${need_pkgs[@]}"; }; then
      echo "Continuing without them: the command line works, the GUI and its tests need them (install them yourself: apt-get install ${need_pkgs[*]})." >&2
    fi
  else
    echo "Warning: missing system libraries for Qt: ${need_pkgs[*]} (install them with your package manager)." >&2
  fi
fi

if [ ! -x "$venv/bin/python" ]; then
  echo "Creating virtual environment in $venv"
  "$py" -m venv "$venv"
fi
stamp="$venv/.lfstudio-installed"
want="$(cat "$here/pyproject.toml" | sha256sum | cut -d' ' -f1)"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  echo "Installing lfstudio and its dependencies into $venv (first run takes a minute)"
  log="$venv/install.log"
  if ! { "$venv/bin/python" -m pip install --disable-pip-version-check --upgrade pip \
         && "$venv/bin/python" -m pip install --disable-pip-version-check -e "$here[test]"; } >"$log" 2>&1; then
    tail -n 30 "$log" >&2
    echo "Installing lfstudio failed; the whole log is in $log" >&2
    exit 1
  fi
  echo "$want" > "$stamp"
fi

# GenICam cameras (genicam:ID) go through aravis's GObject introspection binding: Debian's
# gir1.2-aravis-0.8 and python3-gi (aravis-tools-cli: arv-tool-0.8 lists cameras; aravis-tools: the
# fake GigE Vision camera the tests use). Installed as root with apt-get when missing; then the venv
# sees Debian's `gi` package through a .pth file naming a folder that holds only a link to it (PyPI's
# pygobject >= 3.52 needs girepository-2.0, which Debian 12 lacks). Optional: without them
# genicam:ID says how to install aravis and its tests skip.
if command -v dpkg-query >/dev/null 2>&1; then
  gi_pkgs=()
  for pkg in gir1.2-aravis-0.8 python3-gi aravis-tools-cli aravis-tools; do
    status="$(dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null || true)"
    if [[ "$status" != *"ok installed"* ]]; then gi_pkgs+=("$pkg"); fi
  done
  if [ "${#gi_pkgs[@]}" -gt 0 ] && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "GenICam cameras need aravis: installing ${gi_pkgs[*]} with apt-get (running as root):"
    if ! { apt_step "refresh the package lists" apt-get update -qq \
           && apt_step "install" apt-get install -y -qq "${gi_pkgs[@]}"; }; then
      echo "Continuing without aravis: genicam:ID cameras will not work (apt-get install ${gi_pkgs[*]})." >&2
    fi
  fi
fi
system_gi=/usr/lib/python3/dist-packages/gi
if ! "$venv/bin/python" -c 'import gi' >/dev/null 2>&1 && [ -d "$system_gi" ] \
   && ls "$system_gi"/_gi.cpython-"$("$venv/bin/python" -c 'import sys; print(f"{sys.version_info[0]}{sys.version_info[1]}")')"-*.so >/dev/null 2>&1; then
  mkdir -p "$venv/system-gi" && ln -sfn "$system_gi" "$venv/system-gi/gi"
  "$venv/bin/python" - "$venv/system-gi" <<'PY'
import sys, sysconfig, pathlib
pathlib.Path(sysconfig.get_paths()["purelib"], "lfstudio-system-gi.pth").write_text(sys.argv[1] + "\n")
PY
fi

export LFSTUDIO_PY="$venv/bin/python"
