#!/usr/bin/env bash
# Installs what mjx_hopper needs on a fresh Debian/Ubuntu machine: Mesa's EGL for headless
# rendering, Python's venv where it is missing, and a virtual environment in .venv with the
# project (and, with an argument, that extra of pyproject's: test, cuda, cuda12), every
# dependency upgraded to the newest release that pyproject admits. Safe to run again: it skips
# what is already there. PYTHON picks the interpreter; by default an existing .venv's, else
# Python 3.12 (Colab's) where one is found, on PATH or in pyenv, else python3.
set -euo pipefail
cd "$(dirname "$0")/.."

minor() { "$1" -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")'; }
if [ -x .venv/bin/python ]; then
  if [ -n "${PYTHON:-}" ] && [ "$(minor "$PYTHON" 2>/dev/null)" != "$(minor .venv/bin/python)" ]; then
    echo ".venv is Python $(minor .venv/bin/python), PYTHON=$PYTHON is not: remove .venv to" \
         "make it again with PYTHON" >&2
    exit 1
  fi
  python=.venv/bin/python
else
  python=${PYTHON:-$(bash scripts/python.sh 3.12 || echo python3)}
fi
# JAX, MuJoCo and the rest need Python >= 3.11: say so before anything is downloaded.
if ! "$python" -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
  found=$("$python" -V 2>&1 || true)
  echo "mjx_hopper needs Python >= 3.11 (JAX's floor), and $python is ${found:-missing}:" \
       "install a newer Python and run again with PYTHON=python3.11 (or newer)" >&2
  exit 1
fi
version=$(minor "$python")

packages=(libegl1 libegl-mesa0 libgl1-mesa-dri libgles2)
# Debian's Python leaves ensurepip, which `python -m venv` needs, to pythonX.Y-venv.
[ -x .venv/bin/python ] || "$python" -c 'import ensurepip' 2>/dev/null ||
  packages+=("python$version-venv")
missing=()
if command -v dpkg-query >/dev/null && command -v apt-get >/dev/null; then
  for p in "${packages[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" ||
      missing+=("$p")
  done
else
  echo "no apt-get here: skipped Debian's packages ${packages[*]} (for videos, install your" \
       "system's EGL or OSMesa)"
fi
if [ ${#missing[@]} -gt 0 ]; then
  sudo=""; [ "$(id -u)" -ne 0 ] && sudo="sudo"
  echo "installing Debian packages: ${missing[*]}"
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "${missing[@]}" >/dev/null
fi

[ -x .venv/bin/python ] || "$python" -m venv .venv
extra=""; [ -n "${1:-}" ] && extra="[$1]"
# Every dependency at the newest release in its range, not what the venv already holds.
bash scripts/install.sh .venv -e ".${extra}"
