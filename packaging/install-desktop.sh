#!/usr/bin/env bash
# Put lfstudio into the desktop's application menu for the current user (XDG folders; no root):
#   packaging/install-desktop.sh                 # runs `lfstudio` from PATH (pipx/pip install)
#   packaging/install-desktop.sh /opt/lfstudio/lfstudio   # a bundle (also: ./install-desktop.sh inside it)
#   packaging/install-desktop.sh --uninstall
# Installs the icons into $XDG_DATA_HOME/icons/hicolor and lfstudio.desktop into
# $XDG_DATA_HOME/applications (default ~/.local/share), then refreshes the menu caches if it can.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
data="${XDG_DATA_HOME:-$HOME/.local/share}"
apps="$data/applications"
icons="$data/icons/hicolor"

if [ "${1:-}" = "--uninstall" ]; then
  rm -f "$apps/lfstudio.desktop"
  find "$icons" -path '*/apps/lfstudio.*' -delete 2>/dev/null || true
  command -v update-desktop-database >/dev/null 2>&1 && update-desktop-database -q "$apps" || true
  echo "lfstudio removed from the application menu"
  exit 0
fi

# where the resources and the .desktop template are: a checkout (packaging/..), or a bundle folder
if [ -d "$here/../resources/icons/hicolor" ]; then
  res="$here/../resources"; desktop="$here/lfstudio.desktop"; default_exec="lfstudio"
elif [ -d "$here/_internal/resources/icons/hicolor" ]; then
  res="$here/_internal/resources"; desktop="$here/_internal/share/applications/lfstudio.desktop"
  default_exec="$here/lfstudio"
else
  echo "install-desktop.sh: cannot find resources/icons next to $here" >&2; exit 1
fi
exec_cmd="${1:-$default_exec}"
if [ "$exec_cmd" = "lfstudio" ] && ! command -v lfstudio >/dev/null 2>&1; then
  echo "warning: 'lfstudio' is not on PATH (install it with pipx, or pass the bundle's program path)" >&2
fi

mkdir -p "$apps"
for dir in "$res"/icons/hicolor/*/apps; do
  size="$(basename "$(dirname "$dir")")"
  mkdir -p "$icons/$size/apps"
  cp -f "$dir"/lfstudio.* "$icons/$size/apps/"
done
# quote the path for the Exec key if it contains spaces
case "$exec_cmd" in *" "*) exec_field="\"$exec_cmd\"" ;; *) exec_field="$exec_cmd" ;; esac
sed -e "s|^Exec=.*|Exec=$exec_field gui|" -e "s|^TryExec=.*|TryExec=$exec_cmd|" "$desktop" > "$apps/lfstudio.desktop"
chmod 644 "$apps/lfstudio.desktop"
command -v update-desktop-database >/dev/null 2>&1 && update-desktop-database -q "$apps" || true
command -v gtk-update-icon-cache >/dev/null 2>&1 && gtk-update-icon-cache -q -t "$icons" 2>/dev/null || true
echo "lfstudio added to the application menu: $apps/lfstudio.desktop (runs $exec_cmd)"
