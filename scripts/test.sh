#!/usr/bin/env bash
# The tests: set up with the test extra (PyBullet, the oracle), then run pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh test
exec .venv/bin/python -m pytest "$@"
