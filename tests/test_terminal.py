"""A run's terminal output holds only the project's own lines: no XLA, absl or import warnings,
but for what XLA:CPU logs at each program it loads from the compile cache on some AVX-512 hosts
(LOADER), which no public setting quiets short of hiding every C++ error."""

import re
import subprocess
import sys

from configs import TINY_ARGS

# The project's lines: its header, its train, eval and summary lines, and resuming notes.
OWN = re.compile(r"^(no checkpoint in .*: starting a fresh run|Hopper with d4pg \(cpu\): .*"
                 r"|\[(train|eval)\] .*|learning curves: .*|done: .*)$")

# XLA:CPU's loader reports its own tuning preferences (+prefer-no-gather/scatter), which no host
# lists as features, as missing from the host, and PjRt that it does not version executables.
LOADER = re.compile(r"Target machine feature \+prefer-no-|Assume version compatibility\. "
                    r"PjRt-IFRT does not track")


def test_a_cpu_run_prints_only_the_projects_lines(tmp_path):
  done = subprocess.run(
      [sys.executable, "-m", "mjx_hopper.faces.cli", *TINY_ARGS,
       "--total-env-steps", "80", "--out-dir", str(tmp_path)],
      capture_output=True, text=True, timeout=600, env={**_env(), "JAX_PLATFORMS": "cpu"})
  assert done.returncode == 0, done.stderr[-3000:]
  assert [line for line in done.stderr.splitlines() if not LOADER.search(line)] == []
  lines = done.stdout.splitlines()
  assert [line for line in lines if not OWN.match(line)] == []
  assert lines[-1].startswith("done: 80 env steps")


def _env():
  import os
  return {k: v for k, v in os.environ.items() if k != "TF_CPP_MIN_LOG_LEVEL"}
