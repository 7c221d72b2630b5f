"""Host-side logging between compiled chunks: every row to a CSV (and, when asked, to
TensorBoard and Weights & Biases), and a short terminal line every `log_every` seconds (like
acme's TerminalLogger).

A row is a dict with a "kind" ("train" or "eval"), "env_steps" and numbers. The CSV,
TensorBoard and W&B get every field; the terminal line shows a few (`TRAIN_FIELDS` plus the
agent's learner fields, or `EVAL_FIELDS`), each with its latest value, and leaves out what is
not known yet (no evaluation so far, no episode ended so far).
"""

from __future__ import annotations

import contextlib
import csv
import io
import logging
import math
import os
import time
from typing import Callable, Sequence

from mjx_hopper.process import errors


# (row field, terminal text with {} for its value) pairs.
RETURNS = (("episode_return", "train return {}"), ("eval_return", "eval return {}"))
TRAIN_FIELDS = (("env_steps", "{} env steps"), ("steps_per_s", "{} steps/s")) + RETURNS
EVAL_FIELDS = (("env_steps", "{} env steps"), ("eval_return", "eval return {}"),
               ("eval_return_std", "std {}"), ("eval_length", "episode length {}"))


# Fields whose NaN means "none this time" (no episode ended in the chunk): the latest value
# stands. Any other NaN (a diverged critic, say) is shown as nan.
KEEP_LATEST = ("episode_return",)

Fields = Sequence[tuple[str, str]]


class Unavailable(ValueError):
  """An optional logging service (TensorBoard, W&B) that cannot start; says what to do."""


class Logger:
  """Writes every row to `csv_path`, with `tensorboard_dir` to TensorBoard, and with
  `wandb_project` to a Weights & Biases run of that project (with `wandb_config`, the run's
  config); prints a train row's short line every `log_every` seconds, and every row passed
  with force=True.

  The CSV's columns are those of the first row plus any added later (the file is rewritten
  when a new column appears); a resumed run appends to it. TensorBoard gets each number of a
  row as the scalar "<kind>/<field>" at step env_steps, in a new event file per run. A run
  resumed from `start_step` env steps drops what an interrupted run wrote after that step (a
  process killed after its last checkpoint) from both, as its own rows will replace them.
  W&B gets the same scalars, against the custom x-axis "env_steps" (an evaluation may be
  logged after later training rows). Use as a context manager, or call `close`, to flush
  TensorBoard's file and finish the W&B run.
  """

  def __init__(self, csv_path: str | None, log_every: float = 10.0,
               print_fn: Callable[[str], None] = print, learner_fields: Fields = (),
               tensorboard_dir: str | None = None, start_step: int = 0,
               id_fields: Sequence[str] = (), wandb_project: str | None = None,
               wandb_config: dict | None = None):
    self.wandb = _wandb_run(wandb_project, wandb_config, csv_path, print_fn)  # first: it may fail
    self.csv_path, self.log_every, self.print_fn = csv_path, log_every, print_fn
    self.learner_fields, self.id_fields = tuple(learner_fields), tuple(id_fields)
    self.rows: list[dict] = []
    self.columns: list[str] = []
    self.latest: dict[str, float] = {}  # each field's latest value, this run
    self._last_print = -math.inf
    if csv_path:
      os.makedirs(os.path.dirname(os.path.abspath(csv_path)), exist_ok=True)
      if os.path.exists(csv_path):  # a resumed run appends to its log
        with open(csv_path, newline="") as f:
          reader = csv.DictReader(f)
          self.columns = list(reader.fieldnames or [])
          rows = list(reader)
        self.rows = [r for r in rows if float(r["env_steps"]) <= start_step]
        if len(self.rows) < len(rows):
          self._rewrite_csv()
    self.tensorboard = _tensorboard_writer(tensorboard_dir, start_step)

  def write(self, row: dict, force: bool = False) -> None:
    """Logs one row to every sink: log.csv, TensorBoard, W&B, and the terminal line."""
    row = {k: _plain(v) for k, v in row.items()}
    self.rows.append(row)
    self.latest.update({k: v for k, v in row.items() if _is_number(v)
                        and not (k in KEEP_LATEST and math.isnan(v))})
    if self.csv_path:
      self._write_csv(row)
    if self.tensorboard is not None or self.wandb is not None:
      self._write_scalars(row)
    now = time.monotonic()
    if force or now - self._last_print >= self.log_every:
      self._last_print = now
      self.print_fn(self.line(row))

  def line(self, row: dict) -> str:
    """The terminal line of `row`: "[kind] 51,200 env steps | ...", from the latest values."""
    if row["kind"] == "eval":
      return "[eval] " + self.describe(EVAL_FIELDS)
    text = "[train] " + self.describe(TRAIN_FIELDS)
    if not row.get("learning", 1):  # the learner's figures are zeros until it starts
      return text + " | filling the replay"
    return text + " | " + self.describe(self.learner_fields)

  def describe(self, fields: Fields, sep: str = " | ") -> str:
    """`fields` with their latest values; unknown ones are left out."""
    return sep.join(text.format(_fmt(self.latest[key])) for key, text in fields
                    if key in self.latest)

  def close(self) -> None:
    """Flushes and closes TensorBoard's writer and the W&B run."""
    if self.tensorboard is not None:
      self.tensorboard.close()
    if self.wandb is not None:
      self.wandb.finish()
      self.wandb = None

  def __enter__(self) -> "Logger":
    return self

  def __exit__(self, *exc) -> bool:
    self.close()
    return False

  def _write_csv(self, row: dict) -> None:
    new = [k for k in row if k not in self.columns]
    if new or not os.path.exists(self.csv_path):
      self.columns += new
      self._rewrite_csv()
      return
    with open(self.csv_path, "a", newline="") as f:
      csv.DictWriter(f, self.columns).writerow(row)

  def _rewrite_csv(self) -> None:
    with open(self.csv_path, "w", newline="") as f:
      writer = csv.DictWriter(f, self.columns)
      writer.writeheader()
      writer.writerows(self.rows)

  def _write_scalars(self, row: dict) -> None:
    """Each number of `row` to TensorBoard and W&B as "<kind>/<field>"; a sweep member's as
    "member<i>/<kind>/<field>", leaving out the fields that name the member (`id_fields`)."""
    step = int(row["env_steps"])
    prefix = f"member{row['member']}/" if "member" in row else ""
    scalars = {f"{prefix}{row['kind']}/{key}": value for key, value in row.items()
               if key not in ("env_steps", *self.id_fields) and _is_number(value)}
    if self.tensorboard is not None:
      for tag, value in scalars.items():
        self.tensorboard.add_scalar(tag, value, step)
    if self.wandb is not None:
      self.wandb.log({"env_steps": step, **scalars})


def check_services(wandb_project: str | None, tensorboard_dir: str | None) -> None:
  """Raises Unavailable where a service a run would log to cannot start: tensorboardX or wandb
  missing, or W&B online without a login (checked without the network). Quiet and quick: a run
  calls it before it starts anything."""
  if tensorboard_dir is not None:
    _summary_writer_class()
  if wandb_project is None:
    return
  wandb = _wandb_module()
  if os.environ.get("WANDB_MODE") in ("offline", "dryrun", "disabled"):
    return
  try:
    with contextlib.redirect_stderr(io.StringIO()):  # its notes on where it found a key
      wandb.login(verify=False)
  except wandb.errors.Error as error:
    raise _no_wandb_run(wandb_project, error) from None


def _summary_writer_class():
  try:
    from tensorboardX import SummaryWriter
  except ImportError:
    raise Unavailable("logging to TensorBoard needs tensorboardX: pip install tensorboardX, or "
                      "leave out --tensorboard-dir (tensorboard_dir)") from None
  return SummaryWriter


def _wandb_module():
  try:
    import wandb
  except ImportError:
    raise Unavailable("logging to Weights & Biases needs wandb: in the mjx_hopper checkout, "
                      "pip install -e '.[wandb]'") from None
  return wandb


def _no_wandb_run(project: str, error: Exception) -> Unavailable:
  return Unavailable(f"Weights & Biases cannot start a run of project {project!r} "
                     f"({errors.first_line(error)}): "
                     "log in with `wandb login` (or set WANDB_API_KEY), or log offline with "
                     "WANDB_MODE=offline and upload later with `wandb sync`")


def _tensorboard_writer(directory: str | None, start_step: int):
  """A tensorboardX SummaryWriter on `directory` (None without one), writing to disk every
  10 s. Its event file is new (named by the time in ns, so that two runs started in the same
  second do not share one); a resumed run purges steps after `start_step`, which its
  checkpoint never saw."""
  if directory is None:
    return None
  summary_writer = _summary_writer_class()
  logging.getLogger("tensorboardX.x2num").addFilter(_not_a_nan_notice)
  return summary_writer(directory, purge_step=start_step + 1 if start_step else None,
                        flush_secs=10, filename_suffix=f".{time.time_ns()}")


def _wandb_run(project: str | None, config: dict | None, csv_path: str | None, print_fn):
  """A Weights & Biases run of `project` with `config` (None without a project), its files in
  $WANDB_DIR, else beside `csv_path`. It leaves the terminal's output alone and says where the
  run is in one line. Without the package or a login, an Unavailable error says what to do."""
  if project is None:
    return None
  wandb = _wandb_module()
  folder = os.environ.get("WANDB_DIR") or (os.path.dirname(os.path.abspath(csv_path))
                                            if csv_path else None)
  try:
    run = wandb.init(project=project, config=config, dir=folder,
                     settings=wandb.Settings(console="off", silent=True))
  except wandb.errors.Error as error:  # no API key, a refused one, no connection
    raise _no_wandb_run(project, error) from None
  run.define_metric("env_steps")
  run.define_metric("*", step_metric="env_steps")
  folder = os.path.dirname(run.dir)
  print_fn(f"Weights & Biases: {folder} (offline: `wandb sync {folder}` uploads it)"
           if run.offline else f"Weights & Biases: {run.url}")
  return run


def _not_a_nan_notice(record: logging.LogRecord) -> bool:
  """False for tensorboardX's warning on each NaN scalar: NaNs are logged on purpose (as in
  log.csv), e.g. the train return of a chunk in which no episode ended."""
  return record.getMessage() != "NaN or Inf found in input tensor."


def _is_number(value) -> bool:
  return isinstance(value, (int, float))


def _plain(value):
  try:
    return float(value) if not isinstance(value, (int, str)) else value
  except (TypeError, ValueError):
    return value


def _fmt(value: float) -> str:
  """3 significant digits, or a whole number with thousands' commas from 1,000 on."""
  return f"{value:,.0f}" if abs(value) >= 999.5 else f"{value:.3g}"
