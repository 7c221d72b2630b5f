"""The host loop's logger: short terminal lines, the full CSV, TensorBoard events, and lines
written above a progress bar."""

import csv
import dataclasses
import glob
import io
import json
import os
import struct
import sys

import numpy as np
import pytest
from tensorboardX.proto.event_pb2 import Event, SessionLog
from tensorboardX.record_writer import masked_crc32c
from tqdm import tqdm

from mjx_hopper import agents
from mjx_hopper.run import loop
from mjx_hopper.run.logger import Logger, Unavailable, check_services
from configs import TINY

NAN = float("nan")


def train_row(env_steps, episode_return, learning=1.0, critic_loss=1.23):
  return {"kind": "train", "env_steps": env_steps, "updates": env_steps // 64,
          "wall_s": env_steps / 100, "steps_per_s": 1234.4, "episode_return": episode_return,
          "learning": learning, "critic_loss": critic_loss, "q_mean": 25.67, "q_min": 7.954}


def eval_row(env_steps, eval_return):
  return {"kind": "eval", "env_steps": env_steps, "wall_s": env_steps / 90,
          "eval_return": eval_return, "eval_return_std": 9.945, "eval_length": 39.19}


ROWS = [train_row(1000, NAN, learning=0.0, critic_loss=0.0), train_row(2000, 12.5),
        eval_row(2000, 310.25), train_row(3000, NAN), train_row(4000, 20.0, critic_loss=NAN)]


def read_csv(path):
  with open(path, newline="") as f:
    return list(csv.DictReader(f))


def test_terminal_lines_are_short_and_leave_out_what_is_not_known():
  lines = []
  logger = Logger(None, log_every=0.0, print_fn=lines.append,
                  learner_fields=agents.learner_fields("d4pg"))
  for row in ROWS:
    logger.write(row)
  assert lines == [
      # Before learning, the learner's figures are zeros: none are shown.
      "[train] 1,000 env steps | 1,234 steps/s | filling the replay",
      "[train] 2,000 env steps | 1,234 steps/s | train return 12.5 | critic loss 1.23 | Q 25.7",
      "[eval] 2,000 env steps | eval return 310 | std 9.95 | episode length 39.2",
      # No episode ended in this chunk: the latest train return stands.
      "[train] 3,000 env steps | 1,234 steps/s | train return 12.5 | eval return 310 | "
      "critic loss 1.23 | Q 25.7",
      # A NaN learner figure is news, not "not known yet".
      "[train] 4,000 env steps | 1,234 steps/s | train return 20 | eval return 310 | "
      "critic loss nan | Q 25.7"]


def test_lines_are_printed_every_log_every_seconds_and_when_forced():
  lines = []
  logger = Logger(None, log_every=3600.0, print_fn=lines.append)
  logger.write(ROWS[1])
  logger.write(ROWS[3])
  logger.write(ROWS[2], force=True)
  assert [line.split(" |")[0] for line in lines] == ["[train] 2,000 env steps",
                                                     "[eval] 2,000 env steps"]


def test_every_agent_has_learner_figures():
  assert all(agents.learner_fields(name) for name in agents.list_agents())


def test_csv_keeps_every_field(tmp_path):
  path = tmp_path / "log.csv"
  with Logger(str(path), print_fn=lambda line: None) as logger:
    for row in ROWS:
      logger.write(row)
  rows = read_csv(path)
  assert list(rows[0]) == list(ROWS[0]) + ["eval_return", "eval_return_std", "eval_length"]
  for got, want in zip(rows, ROWS):
    assert {k: v for k, v in got.items() if v != ""} == {k: str(v) for k, v in want.items()}


def read_events(directory):
  """Each event file's events in `directory`, in name order (TensorBoard's reading order). A
  file is records of: length (u64), its masked CRC (u32), an Event, the Event's masked CRC."""
  out = []
  for name in sorted(f for f in os.listdir(directory) if ".tfevents." in f):
    with open(os.path.join(directory, name), "rb") as f:
      data = f.read()
    events, at = [], 0
    while at < len(data):
      length, length_crc = struct.unpack_from("<QI", data, at)
      record = data[at + 12:at + 12 + length]
      (record_crc,) = struct.unpack_from("<I", data, at + 12 + length)
      assert (length_crc, record_crc) == (masked_crc32c(data[at:at + 8]), masked_crc32c(record))
      events.append(Event.FromString(record))
      at += 16 + length
    out.append(events)
  return out


def scalars(event_files):
  """{(tag, step): [values]} as TensorBoard shows them: a SessionLog START at step s (a
  resumed run's purge_step) hides the scalars read before it at steps >= s."""
  seen = {}
  for events in event_files:
    for event in events:
      if event.session_log.status == SessionLog.START:
        seen = {k: v for k, v in seen.items() if k[1] < event.step}
      for value in event.summary.value:
        seen.setdefault((value.tag, event.step), []).append(value.simple_value)
  return seen


def csv_scalars(rows):
  """{(tag, step): [values]} that log.csv's rows should give TensorBoard (as float32)."""
  out = {}
  for row in rows:
    for key, value in row.items():
      if value != "" and key not in ("kind", "env_steps"):
        out.setdefault((f"{row['kind']}/{key}", int(row["env_steps"])), []).append(
            np.float32(value))
  return out


def assert_same(got, want):
  assert sorted(got) == sorted(want)
  for key, values in want.items():
    np.testing.assert_array_equal(got[key], values, err_msg=str(key))  # NaN equals NaN


def test_tensorboard_gets_the_csv_scalars_and_survives_a_resume(tmp_path, caplog):
  csv_path, board = str(tmp_path / "log.csv"), str(tmp_path / "tb")
  # A run logs up to 3,000 env steps, was last checkpointed at 2,000, and is killed.
  with Logger(csv_path, print_fn=lambda line: None, tensorboard_dir=board) as logger:
    for row in ROWS[:4] + [eval_row(3000, 280.0)]:
      logger.write(row)
  assert not caplog.records  # no "NaN or Inf found in input tensor." for each NaN
  first = read_events(board)
  assert len(first) == 1
  assert_same(scalars(first), csv_scalars(read_csv(csv_path)))
  # Resumed from 2,000 env steps, it logs 3,000 and 4,000 again.
  with Logger(csv_path, print_fn=lambda line: None, tensorboard_dir=board,
              start_step=2000) as logger:
    logger.write(train_row(3000, 14.0))
    logger.write(ROWS[4])
  both = read_events(board)
  assert len(both) == 2 and both[0] == first[0]  # appended: the first file is untouched
  rows = read_csv(csv_path)
  # The killed run's rows after 2,000 are gone from both: the resumed run's replace them.
  assert [int(row["env_steps"]) for row in rows] == [1000, 2000, 2000, 3000, 4000]
  assert float(rows[3]["episode_return"]) == 14.0
  assert_same(scalars(both), csv_scalars(rows))


def test_run_writes_tensorboard_and_resumes_it(tmp_path):
  """loop.run with a TensorBoard folder for one chunk writes log.csv's scalars; run again, it
  resumes at 40 env steps and opens a second event file that purges later steps."""
  from configs import TINY
  cfg = dataclasses.replace(TINY, total_env_steps=40, out_dir=str(tmp_path),
                            tensorboard_dir=str(tmp_path / "tb"))
  for _ in range(2):
    loop.run(cfg, progress=False, print_fn=lambda line: None)
  first, resumed = read_events(tmp_path / "tb")
  assert [e.step for e in resumed if e.session_log.status == SessionLog.START] == [41]
  assert_same(scalars([first, resumed]), csv_scalars(read_csv(tmp_path / "log.csv")))


def render(text):
  """The terminal's rows after `text`: each carriage return goes back to column 0."""
  rows = []
  for line in text.split("\n"):
    row = ""
    for part in line.split("\r"):
      row = part + row[len(part):]
    rows.append(row.rstrip())
  return rows


def test_lines_go_above_the_progress_bar(monkeypatch):
  terminal = io.StringIO()
  monkeypatch.setattr(sys, "stdout", terminal)  # the bar and the lines share one terminal
  say = loop._above_progress_bars(print)
  bar = tqdm(total=10, file=terminal, ncols=60, bar_format="{l_bar}{bar}| {n}/{total}")
  bar.update(3)
  say("[train] 3 env steps")
  bar.update(2)
  bar.close()
  rows = render(terminal.getvalue())
  assert rows[0] == "[train] 3 env steps"  # not "30%|###...| 3/10[train] 3 env steps"
  assert rows[1].startswith(" 50%|") and rows[1].endswith("| 5/10") and rows[2:] == [""]


def test_sweep_members_have_their_own_tensorboard_series(tmp_path):
  with Logger(None, tensorboard_dir=str(tmp_path), print_fn=lambda line: None,
              id_fields=("member", "seed", "sigma")) as logger:
    for member, value in ((0, 10.0), (1, 20.0)):
      logger.write({"kind": "eval", "member": member, "seed": member, "sigma": 0.1,
                    "env_steps": 40, "eval_return": value})
  assert scalars(read_events(str(tmp_path))) == {("member0/eval/eval_return", 40): [10.0],
                                                 ("member1/eval/eval_return", 40): [20.0]}


def wandb_records(path):
  """The records of a W&B run file (.wandb): LevelDB's log format, in 32 KiB blocks after a
  7-byte file header; each chunk has a 7-byte header (CRC32C u32, length u16, type u8: 1 a
  whole record, 2 its first chunk, 3 a middle one, 4 its last), and a record is a protobuf."""
  from wandb.proto import wandb_internal_pb2
  with open(path, "rb") as f:
    data = f.read()
  assert data[:4] == b":W&B"
  at, pending, block = 7, b"", 32768
  while at + 7 <= len(data):
    if block - at % block < 7:  # a block's tail too short for a header is padding
      at += block - at % block
      continue
    length, kind = struct.unpack_from("<HB", data, at + 4)
    pending += data[at + 7:at + 7 + length]
    at += 7 + length
    if kind in (1, 4):
      yield wandb_internal_pb2.Record.FromString(pending)
      pending = b""


def test_weights_and_biases_gets_every_scalar_and_the_config(tmp_path, monkeypatch):
  wandb = pytest.importorskip("wandb")
  monkeypatch.setenv("WANDB_MODE", "offline")
  monkeypatch.setenv("WANDB_DIR", str(tmp_path))
  config = {"env": "Hopper", "agent": "d4pg", "seed": 3}
  lines = []
  member_row = {"kind": "eval", "member": 1, "seed": 1, "env_steps": 5000, "eval_return": 9.5}
  with Logger(str(tmp_path / "log.csv"), print_fn=lines.append, wandb_project="mjx_hopper_test",
              wandb_config=config, id_fields=("member", "seed")) as logger:
    for row in ROWS + [member_row]:
      logger.write(row)
  wandb.teardown()  # W&B's service writes its run file in the background: wait for it
  (path,) = glob.glob(str(tmp_path / "wandb" / "offline-run-*" / "run-*.wandb"))
  assert lines[0] == (f"Weights & Biases: {os.path.dirname(path)} (offline: `wandb sync "
                      f"{os.path.dirname(path)}` uploads it)")
  records = list(wandb_records(path))
  (run,) = [r.run for r in records if r.WhichOneof("record_type") == "run"]
  assert run.project == "mjx_hopper_test"
  assert {i.key: json.loads(i.value_json) for i in run.config.update if i.key in config} == config
  history = []
  for r in records:
    if r.WhichOneof("record_type") == "history":
      items = {(i.key or "/".join(i.nested_key)): json.loads(i.value_json)  # "a/b" is nested
               for i in r.history.item}
      history.append({k: v for k, v in items.items() if not k.startswith("_")})  # W&B's own
  want = [{"env_steps": row["env_steps"],
           **{f"{row['kind']}/{k}": v for k, v in row.items() if k not in ("kind", "env_steps")}}
          for row in ROWS]
  want.append({"env_steps": 5000, "member1/eval/eval_return": 9.5})
  assert [sorted(h) for h in history] == [sorted(w) for w in want]
  for got, expected in zip(history, want):
    np.testing.assert_array_equal([got[k] for k in sorted(got)],  # NaN equals NaN
                                  [expected[k] for k in sorted(expected)])
  # The scalars' x-axis is env_steps: an evaluation may be logged after later training rows.
  steps = [r.metric for r in records if r.WhichOneof("record_type") == "metric"]
  assert any(m.glob_name == "*" and m.step_metric == "env_steps" for m in steps)


def test_weights_and_biases_without_wandb_names_the_extra(tmp_path, monkeypatch):
  monkeypatch.setitem(sys.modules, "wandb", None)  # import wandb raises ImportError
  with pytest.raises(Unavailable, match=r"^logging to Weights & Biases needs wandb: in "
                                               r"the mjx_hopper checkout, pip install -e "
                                               r"'\.\[wandb\]'$"):
    Logger(str(tmp_path / "run" / "log.csv"), wandb_project="mjx_hopper_test")
  assert os.listdir(tmp_path) == []  # not even the log's folder


@pytest.fixture
def no_wandb_login(tmp_path, monkeypatch):
  """No W&B API key anywhere: no environment variable, no ~/.netrc, no saved settings."""
  wandb = pytest.importorskip("wandb")
  for name in ("WANDB_API_KEY", "WANDB_MODE", "WANDB_DISABLED", "WANDB_DIR", "WANDB_SILENT"):
    monkeypatch.delenv(name, raising=False)
  for name in ("HOME", "WANDB_CONFIG_DIR", "WANDB_CACHE_DIR", "WANDB_DATA_DIR"):
    monkeypatch.setenv(name, str(tmp_path / "home"))
  monkeypatch.setenv("NETRC", str(tmp_path / "home" / ".netrc"))
  yield
  wandb.teardown()


NO_LOGIN = ("Weights & Biases cannot start a run of project 'mjx_hopper_test' (No API key "
            "configured. Use `wandb login` to log in.): log in with `wandb login` (or set "
            "WANDB_API_KEY), or log offline with WANDB_MODE=offline and upload later with "
            "`wandb sync`")


def test_weights_and_biases_without_a_login_says_how_in_one_line(tmp_path, no_wandb_login):
  with pytest.raises(Unavailable) as error:
    Logger(str(tmp_path / "run" / "log.csv"), wandb_project="mjx_hopper_test")
  assert str(error.value) == NO_LOGIN


def test_a_run_finds_no_login_before_it_starts_anything(tmp_path, no_wandb_login, monkeypatch):
  """Checked first (W&B asks no server for it): a compile under way would hold the process."""
  cfg = dataclasses.replace(TINY, out_dir=str(tmp_path / "run"), wandb="mjx_hopper_test")
  with pytest.raises(Unavailable) as error:
    loop.run(cfg, progress=False)
  assert str(error.value) == NO_LOGIN
  assert not os.path.exists(tmp_path / "run")
  monkeypatch.setenv("WANDB_MODE", "offline")  # offline needs no login
  check_services("mjx_hopper_test", None)


def test_tensorboard_without_its_writer_says_so_in_one_line(tmp_path, monkeypatch):
  monkeypatch.setitem(sys.modules, "tensorboardX", None)
  with pytest.raises(Unavailable, match=r"^logging to TensorBoard needs tensorboardX: pip "
                                               r"install tensorboardX, or leave out "
                                               r"--tensorboard-dir \(tensorboard_dir\)$"):
    Logger(None, tensorboard_dir=str(tmp_path / "tb"))
