"""The record of a run's members: their settings now, lineage, divergence, best evaluations and
whether they reached the run's target. A checkpoint keeps it."""

from __future__ import annotations

import numpy as np


class Members:
  """What a run knows of each of its members, besides its state.

  Two index spaces name members. A member's *index* is its place in
  `RunConfig.member_settings()`: the `member` column of log.csv, what `extract` takes, and what
  `parents` holds. Its *position* is its place along the TrainState's member axis and every
  array here (`indices[position]` is its index; a run over several processes still holds every
  member). A single run has one member, index and position 0.
  """

  def __init__(self, members: list[dict], indices: list[int], single: bool, pbt: bool,
               target: float | None, say):
    self.indices, self.single, self.pbt, self.target, self.say = indices, single, pbt, target, say
    self.values = [dict(m) for m in members]  # seed and swept settings, as PBT leaves them
    self.parents = np.array(indices)          # the index each last copied from (itself: none)
    self.diverged = np.zeros(len(members), bool)
    self.best_return = np.full(len(members), -np.inf)
    self.best_steps = np.full(len(members), -1)
    self.reached = np.zeros(len(members), bool)  # evaluated at `target` or above
    self.reached_at = None  # the env steps of the evaluation where the last got there

  def __len__(self) -> int:
    return len(self.indices)

  def record(self) -> dict:
    """The record, as JSON."""
    return {"values": self.values, "parents": self.parents.tolist(),
            "diverged": self.diverged.tolist(),
            "best_return": [None if np.isinf(v) else float(v) for v in self.best_return],
            "best_env_steps": self.best_steps.tolist()}

  def load_record(self, record: dict) -> None:
    """Takes back a saved record (an older checkpoint's may lack parts). A single run's
    divergence is not kept: it stops unsaved, so its checkpoint holds a finite agent."""
    self.values = record.get("values", self.values)
    self.parents = np.array(record.get("parents", self.parents))
    if not self.single:
      self.diverged = np.array(record.get("diverged", self.diverged), bool)
    self.best_return = np.array([-np.inf if v is None else v for v in
                                 record.get("best_return", self.best_return)], np.float64)
    self.best_steps = np.array(record.get("best_env_steps", self.best_steps))

  def tags(self, position: int) -> dict:
    """The log columns that name a member and its state (none in a single run)."""
    if self.single:
      return {}
    parent = {"parent": int(self.parents[position])} if self.pbt else {}
    return {"member": self.indices[position], **self.values[position], **parent,
            "diverged": int(self.diverged[position])}

  def name(self, position: int) -> str:
    """How the terminal names the member at `position`: "member I " in a sweep, "" alone."""
    return "" if self.single else f"member {self.indices[position]} "

  def check(self, env_steps: int, metrics: dict, finite_params) -> None:
    """Marks diverged the members whose learner metrics or parameters went non-finite."""
    learner = [k for k in metrics if k not in ("episode_return", "episodes", "learning")]
    self.mark_diverged(env_steps, [[k for k in learner if not np.isfinite(metrics[k][m])]
                                   + ([] if finite_params[m] else ["parameters"])
                                   for m in range(len(self))])

  def mark_diverged(self, env_steps: int, bad: list[list[str]]) -> None:
    """Marks diverged each member whose list of non-finite names is not empty, once."""
    for m, names in enumerate(bad):
      if names and not self.diverged[m]:
        self.diverged[m] = True
        frozen = "" if self.single else "; frozen at its last finite agent" + (
            " until PBT replaces it" if self.pbt else "")
        self.say(f"[diverged] {self.name(m)}at {env_steps:,} env steps: {', '.join(names)} not "
                 f"finite{frozen}")

  def evaluated(self, env_steps: int, returns: np.ndarray, diverged_then: np.ndarray):
    """Takes an evaluation's mean returns (one per member); returns which members beat their
    best, leaving out those diverged when their agents were taken (`diverged_then`)."""
    self.mark_diverged(env_steps, [[] if np.isfinite(r) else ["evaluation return"]
                                   for r in returns])
    better = np.isfinite(returns) & (returns > self.best_return) & ~diverged_then
    self.best_return = np.where(better, returns, self.best_return)
    self.best_steps = np.where(better, env_steps, self.best_steps)
    if self.target is not None:
      newly = ~self.reached & (returns >= self.target)
      self.reached |= newly
      if newly.any():
        self.reached_at = env_steps
    return better

  def copied(self, moved, sources, new_values: dict) -> None:
    """PBT's step: members at positions `moved` took the agents of positions `sources[moved]`,
    with settings `new_values` ({name: (members,) values})."""
    for m in moved:
      self.parents[m] = self.indices[sources[m]]
      self.diverged[m] = False
      self.values[m] = {**self.values[m], **{k: _plain(v[m]) for k, v in new_values.items()}}

  def all_diverged(self) -> bool:
    """Whether every member went non-finite."""
    return bool(self.diverged.all())

  def done(self) -> bool:
    """Whether every member reached the target or diverged."""
    return bool((self.reached | self.diverged).all())

  def outcome(self) -> str:
    """Why the run ended early, or "done"."""
    if self.all_diverged():
      return "diverged"
    if not self.done():
      return "done"
    who = "reached" if self.single else "every member reached"
    return (f"{who} {self.target:g}{' or diverged' if self.diverged.any() else ''} by the "
            f"evaluation at {self.reached_at:,} env steps")


def _plain(value):
  """A NumPy number as the Python number a config holds (float32's shortest text)."""
  return int(value) if np.issubdtype(np.asarray(value).dtype, np.integer) else float(
      str(np.float32(value)))
