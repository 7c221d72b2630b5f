#!/usr/bin/env bash
# The tests: set up with the test extra (PyBullet, the oracle), then run pytest on two workers,
# each test file in one of them (its compiled fixtures are built once), the longest files first
# (tests/conftest.py's LONGEST_FIRST).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh test
exec .venv/bin/python -m pytest -n 2 --dist loadfile --no-loadscope-reorder "$@"
