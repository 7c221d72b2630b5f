"""A pytest plugin (tests/conftest.py loads it): the compile ledger of the run. Every test
worker, and every process a test starts, appends what it compiles to a file per test file
(`mjx_hopper.process.ledger`); at the end of the run the controller prints the totals and the
10 test files that compiled longest, so the suite's growth shows in every log."""

import os
import shutil
import tempfile

import pytest

from mjx_hopper.process import ledger

HEAVIEST = 10
_FOLDER = "MJX_HOPPER_LEDGER_FOLDER"  # where the run's ledger files go, set by the controller


def pytest_configure(config):
  if _FOLDER not in os.environ:  # the controller (xdist's workers inherit its environment)
    os.environ[_FOLDER] = tempfile.mkdtemp(prefix="mjx_hopper_ledger_")
    config._ledger_owner = True
  # The ledger's listeners are mjx_hopper.setup's, which conftest calls.


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_protocol(item):
  # The file's events, and those of the processes its tests start, which inherit the variable.
  os.environ[ledger.VARIABLE] = os.path.join(
      os.environ[_FOLDER], f"{item.path.name}.{os.getpid()}.jsonl")


def by_file(folder: str) -> dict[str, list[str]]:
  """The ledger files in `folder`, by the test file they are of."""
  files: dict[str, list[str]] = {}
  for name in os.listdir(folder):
    files.setdefault(name.split(".py.")[0] + ".py", []).append(os.path.join(folder, name))
  return files


def pytest_terminal_summary(terminalreporter, config):
  if not getattr(config, "_ledger_owner", False):
    return
  folder = os.environ[_FOLDER]
  paths = by_file(folder)
  files = {name: ledger.summarise(ps) for name, ps in paths.items()}
  total = ledger.summarise([p for ps in paths.values() for p in ps])
  shutil.rmtree(folder, ignore_errors=True)
  if not files:
    return
  write = terminalreporter.write_line
  terminalreporter.write_sep("=", "compile ledger")
  write(_line("all test files", total))
  write("the trainer configurations: " + ", ".join(sorted(total["trainers"])))
  write(f"the {min(HEAVIEST, len(files))} that compiled longest:")
  for name, totals in sorted(files.items(), key=lambda kv: -kv[1]["compile s"])[:HEAVIEST]:
    write("  " + _line(name, totals))


def _line(name: str, t: dict) -> str:
  return (f"{name}: {t['programs']} programs, {t['compiled']} compiled and {t['cache hits']} "
          f"from the cache, {t['compile s']:.0f} s compiling, {t['trace s']:.0f} s tracing, "
          f"{t['lower s']:.0f} s lowering, {len(t['trainers'])} trainer configurations")
