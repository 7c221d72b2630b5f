#!/usr/bin/env bash
# The tests: set up with the test extra (Python 3.12 where found, the newest releases in range),
# print the Python and JAX versions, then run pytest on two workers, each test file in one of
# them (its compiled fixtures are built once), and the files that build the same programs in
# the same one (tests/conftest.py's GROUPS), the longest first (LONGEST_FIRST), a crashed
# worker replaced twice at most (tests/crashes.py); and the time it all took, its 15 longest
# tests, and what it compiled (tests/ledger.py). The quick tier by default: every test but
# those marked slow (the notebook, every robot's whole episodes, processes of their own), which
# `bash scripts/test.sh -m slow` runs and CI runs after it (.ci/run). Arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
start=$SECONDS
bash scripts/setup.sh test
.venv/bin/python -c 'import sys, jax; print(f"Python {sys.version.split()[0]}, jax {jax.__version__}")'
status=0
.venv/bin/python -m pytest -n 2 --dist loadfile --no-loadscope-reorder --max-worker-restart 2 \
  --durations=15 -m "not slow" "$@" ||
  status=$?
echo "scripts/test.sh: $((SECONDS - start)) s, pytest's exit status $status"
exit $status
