#!/usr/bin/env bash
# The main job: set up, then a 10-minute D4PG training run on Hopper (5M env steps at most).
# Arguments after main.sh go to `mjx-hopper train`; for example --max-minutes 30.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/mjx-hopper train --env Hopper --agent d4pg --preset cpu --steps 5000000 \
  --max-minutes 10 --out runs/main "$@"
