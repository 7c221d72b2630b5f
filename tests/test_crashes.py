"""tests/crashes.py: a test worker's crash fails the run, unless the test passes when run
again and nothing else failed; and the run goes on to its end."""

import os
import resource
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
CRASHING = """
import ctypes, os, time

def test_before():
  pass

def test_crashes():
  time.sleep(1)  # the other worker runs ahead, and the queue empties
  if os.environ["CRASH"] == "always" or not os.path.exists("crashed"):
    open("crashed", "w").close()
    ctypes.string_at(0)  # a segfault

def test_after():
  pass

def test_fails():
  assert os.environ["FAIL"] != "1"
"""


def run(tmp_path, crash: str | None, fail: str = "0", files_before: int = 0
        ) -> subprocess.CompletedProcess:
  """pytest on two workers as scripts/test.sh runs it, over the test files in `tmp_path`,
  `files_before` files of one quick test each and then (unless `crash` is None) CRASHING."""
  (tmp_path / "pytest.ini").write_text("[pytest]\n")
  for i in range(files_before):
    (tmp_path / f"test_a{i:02}.py").write_text("def test_quick():\n  pass\n")
  if crash is not None:
    (tmp_path / "test_crashing.py").write_text(CRASHING)
  return subprocess.run(
      [sys.executable, "-m", "pytest", "-n", "2", "--dist", "loadfile", "--no-loadscope-reorder",
       "-p", "crashes", "-p", "no:cacheprovider", "--max-worker-restart", "2", "-q",
       "-o", "addopts="], cwd=tmp_path, capture_output=True, text=True, timeout=120,
      env={**os.environ, "PYTHONPATH": HERE, "CRASH": str(crash), "FAIL": fail},
      preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_CORE, (0, 0)))  # no core files


def test_a_crash_that_passes_again_passes_the_run(tmp_path):
  done = run(tmp_path, "once")
  assert done.returncode == 0, done.stdout
  assert "a worker died in test_crashing.py::test_crashes (1x): it passed when run again" \
      in done.stdout
  assert "no test failed otherwise: the run passes" in done.stdout


def test_a_crash_beside_a_failure_fails_the_run(tmp_path):
  done = run(tmp_path, "once", fail="1")
  assert done.returncode == 1, done.stdout
  assert "the run passes" not in done.stdout


def test_a_crash_every_time_fails_the_run(tmp_path):
  done = run(tmp_path, "always")
  assert done.returncode != 0, done.stdout
  assert "did not pass when run again" in done.stdout


def test_a_crash_after_finished_files_runs_to_the_end(tmp_path):
  # xdist's own scheduler put the dead worker's finished files back as empty work, on which
  # the workers then waited for good (a TimeoutExpired here).
  done = run(tmp_path, "once", files_before=30)
  assert done.returncode == 0, done.stdout
  assert "34 passed" in done.stdout and "a worker died in test_crashing.py::test_crashes" \
      in done.stdout


GROUPED = """
import os, time

def test_{name}():
  time.sleep(0.5)  # long enough that the other worker asks for work meanwhile
  with open("workers", "a") as f:
    f.write("{name} " + os.environ["PYTEST_XDIST_WORKER"] + "\\n")
"""


def test_the_files_of_a_group_run_in_one_worker(tmp_path):
  # The scheduler takes the unit of work that UNIT_OF_FILE names for a file (conftest.py's
  # groups): files g0 to g3 are one unit, the others one each.
  (tmp_path / "conftest.py").write_text(
      "import os, crashes\n"
      "def pytest_configure(config):\n"
      "  config.stash[crashes.UNIT_OF_FILE] = lambda path: (\n"
      "      'g' if os.path.basename(path).startswith('test_g') else path)\n")
  for name in [f"g{i}" for i in range(4)] + [f"o{i}" for i in range(4)]:
    (tmp_path / f"test_{name}.py").write_text(GROUPED.format(name=name))
  done = run(tmp_path, None)
  assert done.returncode == 0, done.stdout
  workers = dict(line.split() for line in (tmp_path / "workers").read_text().splitlines())
  assert len(workers) == 8 and len({workers[f"g{i}"] for i in range(4)}) == 1
