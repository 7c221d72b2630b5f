#!/usr/bin/env bash
# The main job: set up, then a short default D4PG training run on Hopper (arguments after
# main.sh go to `mjx-hopper train`; for example --max-minutes 30).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/mjx-hopper train --env Hopper --agent d4pg --preset cpu --max-minutes 10 \
  --eval-every 50000 --out runs/main "$@"
