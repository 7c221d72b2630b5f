#!/usr/bin/env bash
# The main job: set up, then run `mjx-hopper demo` (extra arguments go to it).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/mjx-hopper demo "$@"
