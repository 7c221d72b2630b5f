"""Checkpoints lose nothing: a kill -9 mid-save, a full disk, a truncated or deleted file, a
wrong config, a state laid out otherwise, a missing or empty directory; and a resumed run
continues bit for bit, in fresh processes."""

import csv
import dataclasses
import errno
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time

import jax
import numpy as np
import pytest
from etils import epath

import mjx_hopper
from mjx_hopper import agents, store
from mjx_hopper.core import train
from mjx_hopper.faces import cli
from mjx_hopper.run import checkpoints
from mjx_hopper.settings.config import field_defaults
from mjx_hopper.store import failures
from checkpoint_worker import CONFIG, state
from configs import TINY_ARGS

HERE = os.path.dirname(os.path.abspath(__file__))


def saved_steps(directory, *steps):
  mngr = store.manager(str(directory))
  for step in steps:
    store.save(mngr, state(step), CONFIG)
  store.wait_and_record(mngr)
  return mngr


def assert_same(a, b):
  jax.tree.map(lambda x, y: np.testing.assert_array_equal(np.asarray(x), np.asarray(y)), a, b)


def test_killed_mid_save_keeps_the_previous_checkpoint(tmp_path):
  directory = tmp_path / "ckpt"
  proc = subprocess.Popen([sys.executable, os.path.join(HERE, "checkpoint_worker.py"),
                           str(directory)], stdout=subprocess.PIPE, text=True)
  try:
    assert proc.stdout.readline().strip() == "saving step 2"
    deadline = time.monotonic() + 60
    while not any("tmp" in name for name in os.listdir(directory)):
      assert time.monotonic() < deadline, "step 2 never started writing"
      time.sleep(0.001)
    proc.send_signal(signal.SIGKILL)
  finally:
    proc.kill()
    proc.wait()
  leftovers = [name for name in os.listdir(directory) if "tmp" in name]
  assert leftovers, "the kill came after step 2 was finished: make it bigger"
  mngr = store.manager(str(directory))
  assert mngr.all_steps() == [1]
  assert_same(store.read_latest(mngr, state(0), CONFIG)[:2], (state(1), 1))
  # The next run resumes from step 1 and saves over the half-written step.
  store.save(mngr, state(2), CONFIG)
  store.wait_and_record(mngr)
  assert mngr.all_steps() == [1, 2]
  assert_same(store.read_latest(store.manager(str(directory)), state(0), CONFIG)[:2],
              (state(2), 2))


def full_disk(monkeypatch):
  """Orbax's writes of metadata files fail as on a full disk (they run in its writer threads).
  Its commit thread starts late, as on a loaded machine: it then holds an error of its own to
  raise at the next save after the step's first error was raised."""
  def write_text(self, *args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self))
  run = threading.Thread.run

  def late_commit(thread):
    if thread.name == failures.ORBAX_COMMIT_THREAD:
      time.sleep(0.5)
    run(thread)
  monkeypatch.setattr(epath.Path, "write_text", write_text)
  monkeypatch.setattr(threading.Thread, "run", late_commit)


def test_a_failed_save_keeps_the_earlier_checkpoint_and_no_partial_files(tmp_path, monkeypatch,
                                                                         capfd):
  directory = tmp_path / "ckpt"
  mngr = saved_steps(directory, 1)
  capfd.readouterr()
  with monkeypatch.context() as patch:
    full_disk(patch)
    with pytest.raises(store.SaveFailed) as failed:
      store.save(mngr, state(2), CONFIG)
      store.wait_and_record(mngr)
  assert str(failed.value) == (f"checkpoint step 2 was not saved in {directory}: No space left "
                               "on device (ENOSPC); step 1, saved before it, is intact")
  assert sorted(os.listdir(directory)) == ["1", "manifests"]  # no *.orbax-checkpoint-tmp
  err = capfd.readouterr().err  # orbax's tracebacks of it are left out
  assert "Traceback" not in err and "never retrieved" not in err, err
  # The earlier checkpoint resumes bit for bit, and the next save works.
  assert_same(store.read_latest(store.manager(str(directory)), state(0), CONFIG)[:2],
              (state(1), 1))
  store.save(mngr, state(3), CONFIG)
  store.wait_and_record(mngr)
  assert mngr.all_steps() == [1, 3]


class Record:
  def record(self):
    return {}


def test_a_run_keeps_training_through_failed_saves_and_its_last_one_raises(tmp_path,
                                                                          monkeypatch):
  """The policy of docs/checkpoints.md: each failed save is one line (the first says that
  training goes on), a failed last save is raised, and a save that works again says so."""
  lines = []
  saver = store.Saver(saved_steps(tmp_path, 1), CONFIG, 10, 8, lines.append)
  where = f"checkpoint step {{}} was not saved in {tmp_path}: No space left on device (ENOSPC)"

  def no_space(step, args):  # (the first test has orbax's own writer fail, at any moment)
    os.makedirs(tmp_path / f"{step}.orbax-checkpoint-tmp" / "agent")
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
  with monkeypatch.context() as patch:
    patch.setattr(saver.mngr, "save", no_space)
    saver.save(state(2), None, Record())
    saver.save(state(3), None, Record())
    saver.save(state(4), None, Record(), last=True)
    with pytest.raises(store.SaveFailed, match=re.escape(
        where.format(4) + "; 24 env steps are not saved since step 1, which is intact")):
      saver.finish(state(4))
  assert lines == [
      f"WARNING: {where.format(2)}; 8 env steps are not saved since step 1, which is intact; "
      "training goes on, and the next save tries again in 10 min",
      f"WARNING: {where.format(3)}; 16 env steps are not saved since step 1, which is intact"]
  assert sorted(os.listdir(tmp_path)) == ["1", "manifests"]
  saver.save(state(5), None, Record())
  saver.finish(state(5))
  assert lines[2:] == [f"checkpoint step 5 is saved in {tmp_path}, after 2 failed save(s)"]
  assert_same(store.read_latest(store.manager(str(tmp_path)), state(0), CONFIG)[:2],
              (state(5), 5))


def test_a_save_that_cannot_fit_is_refused_without_touching_the_folder(tmp_path, monkeypatch):
  directory = tmp_path / "ckpt"
  mngr = saved_steps(directory, 1)
  before = sorted(os.walk(directory))
  size = sum(os.path.getsize(os.path.join(root, name))
             for root, _, names in os.walk(directory / "1") for name in names)
  usage = shutil.disk_usage(directory)
  monkeypatch.setattr(shutil, "disk_usage", lambda path: usage._replace(free=size - 1))
  with pytest.raises(store.SaveFailed, match=(
      rf"^checkpoint step 2 was not saved in {directory}: a step takes about "
      rf"{size / 1e3:.0f} kB and its disk has {(size - 1) / 1e3:.0f} kB free \(nothing was "
      r"written\); step 1, saved before it, is intact$")):
    store.save(mngr, state(2), CONFIG)
  assert sorted(os.walk(directory)) == before
  # Without an earlier step, the estimate is the arrays' own bytes.
  monkeypatch.setattr(shutil, "disk_usage", lambda path: usage._replace(free=1000))
  with pytest.raises(store.SaveFailed, match="no step is saved there"):
    store.save(store.manager(str(tmp_path / "empty")), state(1), CONFIG)
  assert os.listdir(tmp_path / "empty") == []


def newest_data_file(directory, step):
  files = [os.path.join(root, name) for root, _, names in os.walk(directory / str(step) /
                                                                    "trainer")
           for name in names]
  return max(files, key=os.path.getsize)


@pytest.mark.parametrize("fault", ["truncated", "deleted"])
def test_unreadable_newest_step_falls_back_and_names_the_file(tmp_path, fault):
  directory = tmp_path / "ckpt"
  saved_steps(directory, 1, 2)
  victim = newest_data_file(directory, 2)
  if fault == "truncated":
    with open(victim, "r+b") as f:
      f.truncate(os.path.getsize(victim) // 2)
  else:
    os.remove(victim)
  lines = []
  restored, step, best, record = store.read_latest(
      store.manager(str(directory)), state(0), CONFIG, print_fn=lines.append)
  assert_same(restored, state(1))
  assert best is None and record == {}  # saved without either
  assert step == 1
  warning = next(line for line in lines if line.startswith("WARNING"))
  assert "step 2" in warning and victim in warning
  assert ("is missing" if fault == "deleted" else "bytes") in warning
  assert lines[-1].endswith("step 1")


def test_every_step_unreadable_is_an_error_that_overwrites_nothing(tmp_path):
  directory = tmp_path / "ckpt"
  saved_steps(directory, 1)
  os.remove(newest_data_file(directory, 1))
  before = sorted(os.listdir(directory))
  with pytest.raises(ValueError, match="no readable checkpoint .* nothing was overwritten"):
    store.read_latest(store.manager(str(directory)), state(0), CONFIG, print_fn=print)
  assert sorted(os.listdir(directory)) == before


def test_a_state_laid_out_otherwise_is_named_and_nothing_is_overwritten(tmp_path):
  """A checkpoint whose training state has other leaves than this version builds (an older
  version's, say, before a new dynamic setting) is refused with a warning that says so."""
  directory = tmp_path / "ckpt"
  saved_steps(directory, 1)
  files = store.manifests.files(str(directory))
  fresh = state(0)
  fresh = fresh._replace(agent={**fresh.agent, "new_setting": jax.numpy.zeros(())})
  lines = []
  with pytest.raises(ValueError, match="no readable checkpoint .* nothing was overwritten"):
    store.read_latest(store.manager(str(directory)), fresh, CONFIG, print_fn=lines.append)
  assert len(lines) == 1 and "laid out otherwise than this version of mjx_hopper's" in lines[0]
  assert store.manifests.files(str(directory)) == files


@pytest.mark.parametrize("make", ["missing", "empty"])
def test_missing_or_empty_directory_starts_fresh(tmp_path, make):
  directory = tmp_path / "ckpt"
  if make == "empty":
    directory.mkdir()
  lines = []
  fresh = state(0)
  restored, step, _, _ = store.read_latest(store.manager(str(directory)), fresh, CONFIG,
                                           print_fn=lines.append)
  assert restored is fresh and step is None
  assert lines == [f"no checkpoint in {directory}: starting a fresh run"]


@pytest.mark.parametrize("change", [{"env": "Walker2D"}, {"agent": "mpo"}, {"seed": 1}])
def test_another_config_is_refused_naming_it_and_nothing_is_overwritten(tmp_path, change):
  directory = tmp_path / "ckpt"
  saved_steps(directory, 1)
  files = store.manifests.files(str(directory))
  key = next(iter(change))
  with pytest.raises(store.ConfigMismatch,
                     match=f"from another config \\({key}: saved {CONFIG[key]!r}, now "
                           f"{change[key]!r}\\)"):
    store.read_latest(store.manager(str(directory)), state(0), {**CONFIG, **change})
  assert store.manifests.files(str(directory)) == files


def test_a_checkpoint_without_a_newer_setting_resumes_at_its_default(tmp_path):
  # Saved by a version without `compute_dtype`: its agent_config lacks it, and it ran as the
  # default does. loop.run passes the agent config's defaults.
  now = dataclasses.asdict(agents.config("d4pg", "cpu"))
  older = {k: v for k, v in now.items() if k != "compute_dtype"}
  directory = tmp_path / "ckpt"
  mngr = store.manager(str(directory))
  store.save(mngr, state(1), {**CONFIG, "agent_config": older})
  store.wait_and_record(mngr)
  defaults = {"agent_config": field_defaults(agents.config("d4pg"))}
  assert defaults["agent_config"]["compute_dtype"] == "float32"
  assert_same(store.read_latest(store.manager(str(directory)), state(0),
                                {**CONFIG, "agent_config": now}, print_fn=lambda _: None,
                                defaults=defaults)[0], state(1))
  other = {**CONFIG, "agent_config": {**now, "compute_dtype": "bfloat16"}}
  with pytest.raises(store.ConfigMismatch, match="agent_config: saved .*'float32'.*"
                                                      "now .*'bfloat16'"):
    store.read_latest(store.manager(str(directory)), state(0), other, defaults=defaults)


def test_a_checkpoint_records_its_format(tmp_path):
  mngr = saved_steps(tmp_path / "ckpt", 1)
  saved = store.read_config(mngr, 1)
  assert saved["checkpoint_format"] == store.items.FORMAT
  assert saved["versions"]["mjx_hopper"] == mjx_hopper.__version__


@pytest.mark.parametrize("offset", [-1, 1])
def test_a_checkpoint_of_another_format_is_refused_in_one_line(tmp_path, monkeypatch, offset):
  # A format this version does not read, older or newer: saved as if by another version.
  reads = store.items.FORMAT
  saved_format = reads + offset
  monkeypatch.setattr(store.items, "FORMAT", saved_format)
  directory = tmp_path / "ckpt"
  saved_steps(directory, 1)
  monkeypatch.setattr(store.items, "FORMAT", reads)
  files = store.manifests.files(str(directory))
  with pytest.raises(store.FormatMismatch) as error:
    store.read_latest(store.manager(str(directory)), state(0), CONFIG,
                 print_fn=lambda line: pytest.fail(f"printed {line!r}"))
  message = str(error.value)
  assert "\n" not in message
  assert f"has format {saved_format} (saved by mjx_hopper {mjx_hopper.__version__})" in message
  assert f"reads format {reads}:" in message and "nothing was written" in message
  assert ("or newer" if offset > 0 else "to resume or evaluate it") in message
  assert store.manifests.files(str(directory)) == files


def test_an_old_format_names_the_newest_version_that_reads_it():
  # 0.2.0 saved format 1; this version reads format 2 only. Before formats were recorded
  # (late 0.1.0), neither format nor version was saved: 0.2.0 still reads those too.
  for saved in ({"env": "Hopper", "checkpoint_format": 1, "versions": {"mjx_hopper": "0.2.0"}},
                {"env": "Hopper"}):
    with pytest.raises(store.FormatMismatch) as error:
      store.check_format(saved, "DIR")
    assert (f"mjx_hopper {mjx_hopper.__version__} reads format 2: use mjx_hopper 0.2.0 to "
            "resume or evaluate it, or to export its policy; nothing was written"
            ) in str(error.value)
  assert mjx_hopper.__version__ != "0.2.0"  # a format change is a version change


def test_a_checkpoint_without_a_format_is_format_1(monkeypatch):
  monkeypatch.setattr(store.items, "OLDEST_FORMAT", 1)
  store.check_format({"env": "Hopper"}, "DIR")  # saved before formats were recorded
  monkeypatch.setattr(store.items, "OLDEST_FORMAT", 2)
  monkeypatch.setattr(store.items, "FORMAT", 3)
  with pytest.raises(store.FormatMismatch, match="has format 1 .* reads formats 2 to 3"):
    store.check_format({"env": "Hopper"}, "DIR")


# A tiny D4PG run: 2 chunks of 5 iterations (40 env steps each); learning starts at iteration 3.
TRAIN = TINY_ARGS

# The CLI (argv[2:]) in a fresh process, on the suite's compile cache, which writes to argv[1]
# how many programs XLA compiled and how many came from the cache.
COUNTED = """
import atexit, json, sys
import jax
events = []
jax.monitoring.register_event_listener(lambda name, **kwargs: events.append(name))
atexit.register(lambda: json.dump({
    "compiled": events.count("/jax/compilation_cache/cache_misses"),
    "loaded": events.count("/jax/compilation_cache/cache_hits")}, open(sys.argv[1], "w")))
from mjx_hopper.faces import cli
cli.main(sys.argv[2:])
"""


def train_in_fresh_process(out, steps) -> dict:
  """`mjx-hopper train` of TRAIN to `steps` env steps in a fresh process: what it compiled and
  what it loaded from the compile cache."""
  counts = out.parent / f"{out.name}_{steps}.json"
  subprocess.run([sys.executable, "-c", COUNTED, str(counts), *TRAIN, "--total-env-steps",
                  str(steps), "--out-dir", str(out)], check=True, stdout=subprocess.DEVNULL)
  return json.loads(counts.read_text())


@pytest.mark.slow
def test_resume_is_bit_exact_in_fresh_processes(tmp_path):
  # The straight run here (it compiles the programs, and the compile cache then gives them to
  # the fresh processes); the split run in two fresh processes, the second resuming the
  # first's. Neither compiles a program, small ones included: a second run of a configuration,
  # and its resume after a restart, load every program from the cache. The straight run's
  # trainer (conftest.shared_builds) restores both checkpoints.
  cli.main([*TRAIN, "--total-env-steps", "160", "--out-dir", str(tmp_path / "straight")])
  for counts in (train_in_fresh_process(tmp_path / "split", 80),
                 train_in_fresh_process(tmp_path / "split", 160)):  # resumes at 80 env steps
    assert counts["compiled"] == 0 and counts["loaded"] >= 6, counts
  straight = checkpoints.restore(str(tmp_path / "straight" / "checkpoints"))[1]
  split = checkpoints.restore(str(tmp_path / "split" / "checkpoints"))[1]
  assert train.iterations(straight) == train.iterations(split) == 20
  assert int(straight.updates[0]) > 0
  # Params, target params, optimizer states, replay, env states, keys and counters.
  assert_same(straight, split)
  # Two chunks of the log each: the split run appended to its log rather than restarting it.
  with open(tmp_path / "split" / "log.csv") as f:
    assert sum(line.startswith("train,") for line in f) == 4
  with open(tmp_path / "straight" / "log.csv") as f:
    rows = list(csv.DictReader(f))
  assert [r["kind"] for r in rows].count("eval") == 4
  last_train = [r for r in rows if r["kind"] == "train"][-1]
  for name in ("critic_loss", "q_mean", "policy_grad_norm", "episode_return"):
    assert np.isfinite(float(last_train[name])), name
