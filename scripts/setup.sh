#!/usr/bin/env bash
# Installs what mjx_hopper needs on a fresh Debian/Ubuntu machine: Mesa's EGL for headless
# rendering, and a virtual environment in .venv with the project (and, with an argument, that
# extra of pyproject's: test, cuda, cuda12). Safe to run again: it skips what is already there.
set -euo pipefail
cd "$(dirname "$0")/.."

packages=(libegl1 libegl-mesa0 libgl1-mesa-dri libgles2)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  sudo=""; [ "$(id -u)" -ne 0 ] && sudo="sudo"
  echo "installing Debian packages for headless rendering: ${missing[*]}"
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "${missing[@]}" >/dev/null
fi

pip_install() {  # quiet on success, the whole log on failure
  local log; log=$(mktemp)
  if ! .venv/bin/python -m pip install -q "$@" >"$log" 2>&1; then cat "$log" >&2; exit 1; fi
  rm -f "$log"
}
[ -x .venv/bin/python ] || python3 -m venv .venv
extra=""; [ -n "${1:-}" ] && extra="[$1]"
pip_install --upgrade pip
pip_install -e ".${extra}"
