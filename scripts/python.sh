#!/usr/bin/env bash
# Prints the path of a working Python X.Y (the argument): pythonX.Y on PATH, else pyenv's newest
# X.Y.*; exits 1, printing nothing, where there is none.
set -uo pipefail
want=$1
if command -v "python$want" >/dev/null && "python$want" -c '' 2>/dev/null; then
  command -v "python$want"; exit 0
fi
root=$(pyenv root 2>/dev/null || echo "${PYENV_ROOT:-$HOME/.pyenv}")
for python in $(ls -d "$root/versions/$want".*/bin/"python$want" 2>/dev/null | sort -rV); do
  "$python" -c '' 2>/dev/null && { echo "$python"; exit 0; }
done
exit 1
