"""The trainer's settings (`TrainConfig`: its sizes and replay) and population-based training's
(`PBT`), beside `RunConfig` on the settings floor: what a run is asked to do, checked as given."""

from __future__ import annotations

import dataclasses

from mjx_hopper.settings.fields import check_types, setting


@dataclasses.dataclass(frozen=True)
class TrainConfig:
  """How to train; sizes count transitions (one env step of one env).

  The defaults suit D4PG's cpu defaults on a CPU. `replay_ratio` may differ per member, up to the
  trainer's; the others shape the program.
  """

  num_envs: int = setting(512, "envs stepped at once")
  unroll_length: int = setting(4, "env steps per env per iteration")
  batch_size: int = setting(256, "transitions per update")
  replay_ratio: float = setting(4.0, "samples drawn per transition inserted")
  replay_size: int = setting(1_000_000, "transitions kept in the replay")
  min_replay: int = setting(20_000, "transitions collected before learning starts")
  iterations_per_chunk: int = setting(25, "iterations per compiled chunk")

  def __post_init__(self):
    check_types(self)

  @property
  def steps_per_iteration(self) -> int:
    """Env steps one iteration collects: num_envs x unroll_length."""
    return self.num_envs * self.unroll_length

  @property
  def steps_per_chunk(self) -> int:
    """Env steps one chunk collects."""
    return self.steps_per_iteration * self.iterations_per_chunk

  @property
  def updates_per_iteration(self) -> int:
    """Learner updates per iteration: replay_ratio x its env steps / batch_size, rounded."""
    return round(self.replay_ratio * self.steps_per_iteration / self.batch_size)

  def check(self, num_devices: int = 1) -> None:
    """Raises ValueError naming the first bad setting (a wrong type is refused when made)."""
    for name in ("num_envs", "unroll_length", "batch_size", "iterations_per_chunk"):
      value = getattr(self, name)
      if not isinstance(value, int) or value < 1:
        raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    if self.replay_size < self.batch_size:
      raise ValueError(f"replay_size ({self.replay_size}) must be at least batch_size "
                       f"({self.batch_size})")
    if self.min_replay > self.replay_size:
      raise ValueError(f"min_replay ({self.min_replay}) must be at most replay_size "
                       f"({self.replay_size})")
    updates = self.replay_ratio * self.steps_per_iteration / self.batch_size
    if self.replay_ratio <= 0 or abs(updates - round(updates)) > 1e-9:
      raise ValueError(
          f"replay_ratio * num_envs * unroll_length / batch_size must be a whole number of "
          f"updates >= 1, got {self.replay_ratio} * {self.num_envs} * {self.unroll_length} / "
          f"{self.batch_size} = {updates:g}")
    for name in ("num_envs", "batch_size"):
      if getattr(self, name) % num_devices:
        raise ValueError(f"{name} ({getattr(self, name)}) must divide evenly over the "
                         f"{num_devices} devices")

  @property
  def replay_rows(self) -> int:
    """Rows of the replay ring: at least replay_size / num_envs, a multiple of the unroll."""
    rows = -(-self.replay_size // self.num_envs)
    return -(-rows // self.unroll_length) * self.unroll_length


@dataclasses.dataclass(frozen=True)
class PBT:
  """Population-based training's choices (docs/pbt.md says why each default).

  every: evaluations (their env steps) between two exploit-and-explore steps.
  fraction: the worst `fraction` of the members (at least one), and every diverged member, each
    take a copy of the agent of a healthy member drawn from the best `fraction` (parameters,
    optimizer state, target networks, dynamic settings); each keeps its own replay, envs and
    key, but for a diverged member, whose replay and envs hold non-finite steps: it takes its
    source's too.
  factors: each of the grid's settings of a copy is multiplied by one of these, drawn at random
    (an integer setting moves at least by 1), then clipped to its bounds.
  bounds: {setting: (low, high)}; a setting not given is bounded by the grid's smallest and
    largest value.
  """

  every: int = 2
  fraction: float = 0.25
  factors: tuple[float, ...] = (0.8, 1.25)
  bounds: dict = dataclasses.field(default_factory=dict)

  def __post_init__(self):
    check_types(self)
    if not isinstance(self.every, int) or self.every < 1:
      raise ValueError(f"PBT's every must be an integer >= 1 (evaluations), got {self.every!r}")
    if not 0 < self.fraction <= 0.5:
      raise ValueError(f"PBT's fraction must be in (0, 0.5], got {self.fraction}")
    if not self.factors or any(f <= 0 for f in self.factors):
      raise ValueError(f"PBT's factors must be positive numbers, got {self.factors}")
    bounds = {}
    for name, pair in self.bounds.items():
      if (not isinstance(pair, (tuple, list)) or len(pair) != 2
          or not all(isinstance(v, (int, float)) for v in pair) or not pair[0] < pair[1]):
        raise ValueError(f"PBT's bounds for {name!r} must be (low, high) with low < high, got "
                         f"{pair!r}")
      bounds[name] = tuple(float(v) for v in pair)
    object.__setattr__(self, "bounds", bounds)

  def check(self, grid: dict, num_members: int, config_of) -> None:
    """Raises ValueError when this PBT cannot run on `grid`'s `num_members` members (per
    process): fewer than 2, nothing to perturb, a bound on an unswept setting, a bound that
    `config_of(name, value)` (which raises ValueError) refuses."""
    if num_members < 2:
      raise ValueError(f"PBT needs at least 2 members (per process), got {num_members}")
    if not grid:
      raise ValueError("PBT perturbs the grid's settings: give it at least one, such as "
                       "grid={'learning_rate': (1e-4, 1e-3)}")
    for name in self.bounds:
      if name not in grid:
        raise ValueError(f"PBT's bounds name {name!r}, which the grid does not sweep; it "
                         f"sweeps {sorted(grid)}")
    for name, (low, high) in self.ranges(grid).items():
      if low == high:
        raise ValueError(f"PBT cannot perturb {name!r}: the grid has one value, {low:g}; give "
                         "two or more, or bounds={name: (low, high)}")
      for value in (low, high):
        config_of(name, int(value) if isinstance(grid[name][0], int) else value)

  def ranges(self, grid: dict) -> dict[str, tuple[float, float]]:
    """Each swept setting's (low, high)."""
    return {name: self.bounds.get(name, (min(values), max(values)))
            for name, values in grid.items()}
