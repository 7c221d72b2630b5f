"""A run's folder, and the one reader of its layout: `out_dir/config.json` (the config item
without its record), `log.csv`, `checkpoints/` (whose config item holds the config, the
members' indices, the number of processes of a run over several, and the members' record).
A member is named by its index in the sweep (log.csv's `member`); a checkpoint holds them at
positions 0, 1, ... along its member axis.
"""

from __future__ import annotations

import dataclasses
import json
import os
from typing import TYPE_CHECKING, Any

import numpy as np

from mjx_hopper.settings.config import RunConfig
from mjx_hopper.store.items import (ConfigMismatch, has_best, manager, read_config,
                                    read_agent)

if TYPE_CHECKING:  # orbax is imported where a checkpoint is first opened (store.items)
  import orbax.checkpoint as ocp

CONFIG, LOG, CHECKPOINTS = "config.json", "log.csv", "checkpoints"


class RunFolder:
  """The files of one run in `path` (one folder, however many processes train it)."""

  def __init__(self, path: str):
    self.path = path

  @property
  def log(self) -> str:
    """The run's log.csv."""
    return os.path.join(self.path, LOG)

  @property
  def checkpoints(self) -> str:
    """The run's checkpoints folder."""
    return os.path.join(self.path, CHECKPOINTS)

  def write_config(self, item: dict) -> None:
    """Writes config.json: a checkpoint's config `item` (`RunConfig.saved`)."""
    with open(os.path.join(self.path, CONFIG), "w") as f:
      json.dump(item, f, indent=1)

  def grid(self) -> dict:
    """The sweep's grid that config.json holds ({} for a single run, or where it cannot be
    read)."""
    try:
      with open(os.path.join(self.path, CONFIG)) as f:
        return json.load(f).get("grid") or {}
    except (OSError, ValueError):
      return {}


def check_processes(mngr: ocp.CheckpointManager, processes: int) -> None:
  """A ConfigMismatch where the newest checkpoint was saved by a run over another number of
  processes than `processes` (its members' layout over the devices, and so its numbers, would
  differ)."""
  step = mngr.latest_step()
  if step is None:
    return
  try:
    saved = read_config(mngr, step).get("processes", 1)  # RunConfig.saved
  except ConfigMismatch:
    raise
  except Exception:  # noqa: BLE001 - an unreadable step: `store.read_latest` says so
    return
  if saved != processes:
    raise ConfigMismatch(
        f"the checkpoint in {mngr.directory} was saved by a run over {saved} process(es), and "
        f"this run has {processes}: resume it on {saved}; nothing was written")


def open_checkpoints(directory: str) -> ocp.CheckpointManager:
  """The checkpoint manager of `directory`; a FileNotFoundError where it holds none."""
  if not os.path.isdir(directory):
    raise FileNotFoundError(f"no checkpoint directory {directory!r}")
  mngr = manager(directory)
  if not mngr.all_steps():
    raise FileNotFoundError(f"no checkpoint in {directory!r}")
  return mngr


@dataclasses.dataclass(frozen=True)
class Saved:
  """What one checkpoint step of a run holds: its config, its members, their record."""

  directory: str
  step: int
  item: dict           # the config item as saved
  config: RunConfig

  @classmethod
  def read(cls, mngr: ocp.CheckpointManager, step: int, env: Any = None) -> "Saved":
    """Step `step` of `mngr`; `env` is the run's task, for one that cannot be imported. A task
    that cannot be found, or is not `env`, is a ConfigMismatch: no older step does better."""
    item = read_config(mngr, step)
    try:
      cfg = RunConfig.from_json(item, env)
    except ValueError as error:
      raise ConfigMismatch(f"{mngr.directory}: {error}") from None
    return cls(mngr.directory, step, item, cfg)

  @property
  def indices(self) -> list[int]:
    """The indices of the members the step holds, in position order."""
    return list(self.item.get("member_indices", range(len(self.config.member_settings()))))

  @property
  def record(self) -> dict:
    """The members' record: best evaluations, divergence, settings now, lineage."""
    return self.item.get("record", {})

  def member_settings(self) -> list[dict]:
    """The seed and swept values each held member started from, in position order."""
    everyone = self.config.member_settings()
    return [everyone[i] for i in self.indices]

  def best_index(self) -> int:
    """The index of the member with the best saved evaluation; a ConfigMismatch where none
    was saved (no older step has one either)."""
    scores = [-np.inf if v is None else v for v in self.record.get("best_return", [None])]
    if not np.isfinite(scores).any():
      raise ConfigMismatch(f"{self.directory}: no evaluation was saved yet, so no member is "
                           "the best; give a member's index")
    return self.indices[int(np.argmax(scores))]

  def position(self, member: int | str | None) -> int:
    """The position of `member`: an index (log.csv's member), "best", or None for the only
    member of a single run. Anything else is a ConfigMismatch naming the members held."""
    indices = self.indices
    if member is None:
      if len(indices) > 1:
        raise ConfigMismatch(f"{self.directory} holds a sweep of {len(indices)} members: give "
                             "a member's index (--member INDEX, or --member best)")
      return 0
    if member == "best":
      member = self.best_index()
    if isinstance(member, bool) or not isinstance(member, (int, np.integer)):
      raise ConfigMismatch(f"member takes a member's index or 'best', got {member!r}")
    if member not in indices:
      raise ConfigMismatch(f"member {member} is not in {self.directory}: it holds members "
                           f"{indices}")
    return indices.index(member)

  def agents(self, mngr: ocp.CheckpointManager, like, which: str = "best"):
    """(the members' agents at their best evaluations, or with which="latest" or where none
    was saved, the latest; whether they are the best)."""
    best = which == "best" and has_best(mngr, self.step)
    return read_agent(mngr, self.step, like, "best" if best else "agent"), best
