#!/usr/bin/env bash
# Installs into the virtual environment VENV what the other arguments name (as `pip install`
# takes them: -c FILE, -e ".[test]"), each package at the newest release allowed, through uv
# (a PyPI package that fetches and unpacks in parallel: a fresh environment in a fraction of
# pip's time), or through pip where uv cannot be installed or fails. Quiet on success; the
# whole log on failure. Used by scripts/setup.sh and .ci/floor.
# Usage: bash scripts/install.sh VENV ARGS...
set -euo pipefail
venv=$1; shift
log=$(mktemp)
trap 'rm -f "$log"' EXIT
if { [ -x "$venv/bin/uv" ] || "$venv/bin/python" -m pip install -q uv >"$log" 2>&1; } &&
   "$venv/bin/uv" pip install -q --python "$venv/bin/python" --upgrade "$@" >"$log" 2>&1; then
  exit 0
fi
[ -x "$venv/bin/uv" ] && echo "uv could not install $*; pip will (uv's log: $(tail -1 "$log"))"
if ! { "$venv/bin/python" -m pip install -q --upgrade pip &&
       "$venv/bin/python" -m pip install -q --upgrade --upgrade-strategy eager "$@"; } \
     >"$log" 2>&1; then
  cat "$log" >&2
  exit 1
fi
