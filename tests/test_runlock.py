"""One writer per run folder: a second run is refused naming the first, a dead or silent holder's
lock is taken over, and reading a run (eval, export, extract) takes no lock."""

import dataclasses
import json
import os
import socket
import subprocess
import sys
import time

import pytest

from mjx_hopper.faces import cli
from mjx_hopper.process import runlock
from mjx_hopper.run import loop
from configs import TINY, TINY_ARGS

HOLD = ("import sys, time; from mjx_hopper.process import runlock\n"
        "with runlock.hold(sys.argv[1]):\n"
        "  print('held', flush=True); time.sleep(120)")


@pytest.fixture
def held(tmp_path):
  """A folder whose lock another live process holds: (folder, that process)."""
  folder = tmp_path / "run"
  proc = subprocess.Popen([sys.executable, "-c", HOLD, str(folder)], stdout=subprocess.PIPE,
                          text=True)
  try:
    assert proc.stdout.readline().strip() == "held"
    yield folder, proc
  finally:
    proc.kill()
    proc.wait()


def write_lock(folder, **holder):
  os.makedirs(folder, exist_ok=True)
  with open(folder / runlock.LOCK, "w") as f:
    json.dump({"host": socket.gethostname(), "pid": os.getpid(), "token": "theirs",
               "started": time.time(), "heartbeat": time.time(), **holder}, f)


def test_a_second_run_is_refused_naming_the_first_and_writes_nothing(held, capsys):
  folder, proc = held
  with pytest.raises(runlock.Locked, match=(
      rf"^{folder} is in use by another run \(process {proc.pid} on {socket.gethostname()}, "
      r"heartbeat \d+ s ago\): wait for it to end, or train in another folder\. If that run is "
      rf"gone, its lock is taken over once its heartbeat is 10 min old, or delete "
      rf"{folder / runlock.LOCK}$")):
    loop.run(dataclasses.replace(TINY, out_dir=str(folder)), progress=False)
  assert os.listdir(folder) == [runlock.LOCK]  # no config, log or checkpoint
  # The command line says it in one line.
  with pytest.raises(SystemExit, match=rf"^mjx-hopper train: {folder} is in use by another "
                                       rf"run \(process {proc.pid} "):
    cli.main([*TINY_ARGS, "--total-env-steps", "80", "--out-dir", str(folder)])
  assert os.listdir(folder) == [runlock.LOCK]


def test_a_dead_or_silent_holders_lock_is_taken_over_in_one_line(tmp_path, monkeypatch):
  ended = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                         capture_output=True, text=True, check=True)
  lines = []
  write_lock(tmp_path, pid=int(ended.stdout))
  with runlock.hold(str(tmp_path), lines.append):
    assert json.load(open(tmp_path / runlock.LOCK))["pid"] == os.getpid()
  assert lines == [f"taking over {tmp_path / runlock.LOCK} from process {ended.stdout.strip()} "
                   f"on {socket.gethostname()}, which has ended"]
  assert not os.path.exists(tmp_path / runlock.LOCK)  # released
  # Another host's lock: refused while its heartbeat is fresh, taken over once it is stale.
  write_lock(tmp_path, host="colab-elsewhere", pid=7)
  with pytest.raises(runlock.Locked, match=r"\(process 7 on colab-elsewhere, heartbeat 0 s ago"):
    with runlock.hold(str(tmp_path), lines.append):
      pass
  write_lock(tmp_path, host="colab-elsewhere", pid=7, heartbeat=time.time() - 3600)
  with runlock.hold(str(tmp_path), lines.append):
    pass
  assert lines[1] == (f"taking over {tmp_path / runlock.LOCK} from process 7 on colab-elsewhere, "
                      "which has not refreshed its heartbeat for 60 min")
  # An unreadable lock counts from when it was written.
  (tmp_path / runlock.LOCK).write_text("")
  with pytest.raises(runlock.Locked, match=r"\(an unreadable lock\)"):
    with runlock.hold(str(tmp_path), lines.append):
      pass
  os.utime(tmp_path / runlock.LOCK, (time.time() - 3600,) * 2)
  with runlock.hold(str(tmp_path), lines.append):
    pass


def test_the_heartbeat_is_refreshed_while_held(tmp_path, monkeypatch):
  monkeypatch.setattr(runlock, "HEARTBEAT_S", 0.01)
  with runlock.hold(str(tmp_path), print):
    first = json.load(open(tmp_path / runlock.LOCK))["heartbeat"]
    deadline = time.monotonic() + 10
    while json.load(open(tmp_path / runlock.LOCK))["heartbeat"] == first:
      assert time.monotonic() < deadline, "the heartbeat was never refreshed"
      time.sleep(0.01)
    # The same process cannot hold it twice (a second run in a notebook's thread).
    with pytest.raises(runlock.Locked, match=f"process {os.getpid()} on"):
      with runlock.hold(str(tmp_path), print):
        pass
