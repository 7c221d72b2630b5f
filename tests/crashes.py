"""A pytest plugin (tests/conftest.py loads it) for worker crashes, as the controller of
`pytest -n` sees them. A worker that dies in native code (XLA's compiler has segfaulted in
CI, never on our own machines) is replaced, and its file goes on in the new worker from the
test it died in. A run whose only failures are such crashes, at most MAX_CRASHES of them and
each test passing when run again, passes, and says so; a test that crashes every time fails.
Its scheduler keeps a crash from stalling the run, and the files of a group together in one
worker (LoadFileAfterCrashes)."""

import collections
from collections.abc import Callable

import pytest
from xdist.scheduler import LoadFileScheduling

MAX_CRASHES = 2
_crashes: collections.Counter = collections.Counter()
_failed: set[str] = set()
_passed: set[str] = set()


# What the scheduler runs as one unit in one worker, from a test file's path: conftest puts
# its groups of files here (any file not in one is a unit of its own).
UNIT_OF_FILE = pytest.StashKey[Callable[[str], str]]()


class LoadFileAfterCrashes(LoadFileScheduling):
  """xdist's `--dist loadfile` with a file's unit of work as UNIT_OF_FILE names it (xdist's
  own `loadgroup` names none under pytest 9.2: it sets `item._nodeid`, which pytest no longer
  reads), less two ways in which a crash stalls the run for good (pytest-xdist issues 1327 and
  1378; 3.8.0, the newest release, has both): the dead worker's finished files went back on
  the queue as empty units of work, and a worker could be left holding one test, which it
  runs only once it is sent the next test or told to stop."""

  def _split_scope(self, nodeid):
    path = super()._split_scope(nodeid)
    return self.config.stash.get(UNIT_OF_FILE, lambda path: path)(path)

  def remove_node(self, node):
    workload = self.assigned_work[node]
    if self._pending_of(workload):  # it crashed: only its unfinished files go back
      for scope in [scope for scope, unit in workload.items() if all(unit.values())]:
        del workload[scope]
    return super().remove_node(node)

  def _reschedule(self, node):
    super()._reschedule(node)
    if node.shutting_down or self._pending_of(self.assigned_work[node]) != 1:
      return
    if self.workqueue:
      self._assign_work_unit(node)
    else:
      node.shutdown()


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
  if config.getvalue("dist") == "loadfile":
    return LoadFileAfterCrashes(config, log)
  return None


@pytest.hookimpl(optionalhook=True)
def pytest_handlecrashitem(crashitem, report, sched):
  _crashes[crashitem] += 1


def pytest_runtest_logreport(report):
  if report.when == "???":  # xdist's report of a crash, counted in _crashes
    return
  if report.failed:
    _failed.add(report.nodeid)
  elif report.when == "call" and report.passed:
    _passed.add(report.nodeid)


def forgiven() -> bool:
  """Whether the run's only failures were crashes that passed when run again."""
  return (0 < _crashes.total() <= MAX_CRASHES and not _failed
          and all(nodeid in _passed for nodeid in _crashes))


def pytest_terminal_summary(terminalreporter):
  if _crashes:
    terminalreporter.write_sep("=", "worker crashes")
    for nodeid, times in _crashes.items():
      again = "passed when run again" if nodeid in _passed else "did not pass when run again"
      terminalreporter.write_line(f"a worker died in {nodeid} ({times}x): it {again}")
    if forgiven():
      terminalreporter.write_line("no test failed otherwise: the run passes")


def pytest_sessionfinish(session, exitstatus):
  if exitstatus == pytest.ExitCode.TESTS_FAILED and forgiven():
    session.exitstatus = pytest.ExitCode.OK
