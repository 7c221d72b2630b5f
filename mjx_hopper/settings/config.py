"""A run's settings in one frozen dataclass. Each field carries its default, type and help, and
the command line is made from them (`mjx_hopper.faces.cli`).

    from mjx_hopper.settings import config
    cfg = config.RunConfig(env="Hopper", agent="d4pg", total_env_steps=200_000)
"""

from __future__ import annotations

import dataclasses
import itertools
import json
from typing import Any

import mjx_hopper
from mjx_hopper import agents, envs
from mjx_hopper.settings.fields import setting
from mjx_hopper.settings.training import PBT, TrainConfig

EVAL_ON = ("auto", "host", "train")
# A saved config (a checkpoint's config item, config.json): RunConfig's fields, resolved
# (`RunConfig.saved`), and these.
SAVED_EXTRAS = ("agent_config", "member_indices", "processes", "record", "versions",
                "checkpoint_format")
# The saved settings that a checkpoint's state depends on, which a run resuming it must share;
# the others (run length, logging, evaluation) may change between a run and its resumption.
MUST_MATCH = ("env", "env_settings", "agent", "agent_config", "train", "episode_steps", "seed",
              "seeds", "grid", "pbt", "member_indices")
TRAINER_DYNAMIC = ("replay_ratio",)  # the trainer's settings a sweep may vary
# Saved settings renamed within checkpoint format 2, read under their new names: {old: new}.
RENAMED_IN_FORMAT_2 = {"agent_preset": "agent_defaults"}


@dataclasses.dataclass(frozen=True)
class RunConfig:
  """A whole training run: what to train, how, for how long, and where its files go.

  A sweep is a run of several members: `seeds` times the combinations of `grid`'s values,
  trained at once in one program; `pbt` makes them a population (docs/pbt.md). `env` is a
  robot's name, a registered name, a `module:Class` path, or a task class or instance.
  """

  env: Any = setting("Hopper", "a robot (Hopper, Walker2D, HalfCheetah, Ant, Humanoid), or a "
                    "task of your own as module:Class")
  env_settings: dict = setting({}, "the task's constructor settings", flag=False)
  agent: str = setting("d4pg", "the agent: d4pg, ddpg, mpo, dmpo, or one registered with "
                      "agents.register")
  agent_defaults: str = setting("cpu", "the agent's named settings it starts from: cpu, gpu or "
                               "acme (the NMA notebook's acme settings)")
  agent_overrides: dict = setting({}, "agent settings that replace its defaults'", flag=False)
  train: TrainConfig = setting(TrainConfig(), "the trainer's layout", flag=False)
  total_env_steps: int = setting(1_000_000, "env steps to train for")
  max_minutes: float | None = setting(None, "also stop (and save) after the chunk that ends "
                                     "past this much wall-clock time (a run trains at least "
                                     "one chunk)")
  stop_at_return: float | None = setting(None, "also stop once an evaluation of every member "
                                        "reaches this return")
  episode_steps: int | None = setting(None, "the task's time limit in steps; None: the task's "
                                     "own (1000 for the robots)")
  physics: str = setting("mjx", "the physics engine: mjx (MJX, on any device) or c (MuJoCo C "
                        "on the CPU, which compiles and steps faster there)")
  eval_every: int = setting(200_000, "env steps between evaluations")
  eval_episodes: int = setting(16, "episodes per evaluation")
  eval_on: str = setting("auto", "where evaluations run: host (the host's CPU, beside "
                        "training), train (the training's devices, which wait), or auto (host "
                        "for a single run on an accelerator)")
  seed: int = setting(0, "the random seed (a sweep's first seed)")
  seeds: tuple = setting((), "a sweep's seeds (default: just seed)", flag=False)
  grid: dict = setting({}, "a sweep's {dynamic setting: values}", flag=False)
  pbt: PBT | None = setting(None, "population-based training of a sweep's members", flag=False)
  out_dir: str = setting("runs/train", "folder for log.csv, config.json and checkpoints/")
  tensorboard_dir: str | None = setting(None, "also write log.csv's scalars here as "
                                       "TensorBoard events")
  wandb: str | None = setting(None, "also log to this Weights & Biases project (the wandb "
                             "extra: pip install -e '.[wandb]')")
  log_every: float = setting(10.0, "seconds between terminal lines")
  checkpoint_minutes: float = setting(10.0, "minutes between checkpoints")
  keep_checkpoints: int = setting(3, "checkpoints kept")

  def __post_init__(self):
    settings = self.task_settings()  # raises on an unknown task or setting
    if not isinstance(self.agent, str):
      raise ValueError(f"agent takes an agent's name, got {self.agent!r}")
    agents.config(self.agent, self.agent_defaults, **self.agent_overrides)
    for name in ("total_env_steps", "eval_every", "eval_episodes"):
      if getattr(self, name) < 1:
        raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
    if settings["episode_steps"] < 1:
      raise ValueError(f"episode_steps must be >= 1, got {settings['episode_steps']}")
    if self.physics not in envs.PHYSICS:
      raise ValueError(f"physics must be one of {', '.join(envs.PHYSICS)}, got "
                       f"{self.physics!r}")
    if isinstance(self.env, envs.LocomotionEnv) and self.env.physics != self.physics:
      raise ValueError(f"the env given was built with physics={self.env.physics!r}, and the "
                       f"run's physics is {self.physics!r}: give RunConfig the same")
    if self.eval_on not in EVAL_ON:
      raise ValueError(f"eval_on must be one of {', '.join(EVAL_ON)}, got {self.eval_on!r}")
    if len(set(self.seeds)) != len(self.seeds) or not all(
        isinstance(s, int) for s in self.seeds):
      raise ValueError(f"seeds must be distinct integers, got {list(self.seeds)}")
    self.train.check()
    check_grid(self.agent, self.agent_defaults, self.grid, self.train, self.agent_overrides)
    if self.pbt is not None:
      if not isinstance(self.pbt, PBT):
        raise ValueError(f"pbt takes a PBT (mjx_hopper.settings.training) or None, got "
                         f"{self.pbt!r}")
      self.pbt.check(self.grid, len(self.member_settings()), lambda name, value: check_value(
          self.agent, self.agent_defaults, name, value, self.train, self.agent_overrides))

  def task(self) -> type[envs.LocomotionEnv]:
    """The task's class, from `env` (a name, a `module:Class` path, a class or an instance)."""
    return envs.task_class(self.env)

  @property
  def task_id(self) -> str:
    """The task's id (`envs.task_id`): what a checkpoint records."""
    return envs.task_id(self.task())

  def task_settings(self) -> dict:
    """Every constructor setting of the task, defaults and `episode_steps` included. An
    instance's own settings count as given; `env_settings` wins over `episode_steps`."""
    given = {**(envs.settings_of(self.env) if isinstance(self.env, envs.LocomotionEnv) else {}),
             **({} if self.episode_steps is None else {"episode_steps": self.episode_steps}),
             **self.env_settings}
    return envs.task_settings(self.task(), given)

  def make_env(self, task_settings: dict | None = None) -> envs.LocomotionEnv:
    """The task's env, built with its settings (`task_settings`: those already resolved)."""
    if task_settings is None:
      task_settings = self.task_settings()
    return envs.make(self.task(), physics=self.physics, **task_settings)

  def evaluates_on_host(self, backend: str, members: int) -> bool:
    """Whether evaluations of `members` members run on the host's CPU, beside training on
    `backend` (as `jax.default_backend()` names it): `eval_on`."""
    if self.eval_on == "auto":
      return members == 1 and backend != "cpu"
    return self.eval_on == "host"

  def member_settings(self) -> list[dict]:
    """Each member's seed and swept values, in member order (one member for a single run)."""
    return member_settings(tuple(self.seeds) or (self.seed,), self.grid)

  def agent_config(self):
    """The agent's config; in a sweep of n-step values, n_step is the largest a member may have
    (the window the replay reads), each member using its own."""
    window = {"n_step": int(self._largest("n_step"))} if "n_step" in self.grid else {}
    return agents.config(self.agent, self.agent_defaults, **{**self.agent_overrides, **window})

  def train_config(self) -> TrainConfig:
    """The trainer's config; in a sweep of replay ratios, the largest a member may have."""
    if "replay_ratio" not in self.grid:
      return self.train
    return dataclasses.replace(self.train, replay_ratio=self._largest("replay_ratio"))

  def _largest(self, name: str):
    return self.pbt.ranges(self.grid)[name][1] if self.pbt else max(self.grid[name])

  def to_json(self, task_settings: dict | None = None, agent_config=None) -> dict:
    """The config as a checkpoint and config.json record it: the task by id, with every
    setting resolved (`task_settings` and `agent_config`: those already resolved)."""
    out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
    settings = dict(self.task_settings() if task_settings is None else task_settings)
    out.update(env=self.task_id, episode_steps=settings.pop("episode_steps"),
               env_settings=settings, train=dataclasses.asdict(self.train),
               pbt=None if self.pbt is None else dataclasses.asdict(self.pbt),
               agent_config=dataclasses.asdict(
                   self.agent_config() if agent_config is None else agent_config))
    return json.loads(json.dumps(out))

  def saved(self, indices: list[int], processes: int = 1, task_settings: dict | None = None,
            agent_config=None) -> dict:
    """What a checkpoint's config item and config.json hold of this run training members
    `indices` over `processes` (its record is added at each save); `task_settings` and
    `agent_config` as `to_json`'s."""
    item = {**self.to_json(task_settings, agent_config), "member_indices": list(indices)}
    if processes > 1:
      item["processes"] = processes
    return item

  def saved_defaults(self, agent_config=None) -> dict:
    """{saved key: {setting: default}} for the nested settings in MUST_MATCH: what a config
    saved before a setting existed ran with (a newer agent setting at its default)."""
    if agent_config is None:
      agent_config = self.agent_config()
    return {"agent_config": field_defaults(agent_config), "env_settings": {}}

  @classmethod
  def from_json(cls, saved: dict, env: Any = None) -> "RunConfig":
    """The RunConfig that `to_json` saved. `env`, when given, is its task (a class defined in
    a notebook cannot be imported by another process), which must be the saved one: another is
    a ValueError saying which. A setting this version does not know, or a value it refuses (an
    older version's name), is a ValueError naming the saved format and this version."""
    fields = {f.name for f in dataclasses.fields(cls)}
    saved = {RENAMED_IN_FORMAT_2.get(k, k): v for k, v in saved.items()}
    unknown = sorted(set(saved) - fields - set(SAVED_EXTRAS))
    if unknown:
      raise ValueError(_unreadable(saved, f"settings it does not know: {', '.join(unknown)}"))
    kwargs = {k: v for k, v in saved.items() if k in fields}
    if env is not None:
      task = envs.task_class(env)
      mine = envs.task_id(task)
      saved_settings = {"episode_steps": saved["episode_steps"], **saved.get("env_settings", {})}
      settings = (json.loads(json.dumps(envs.settings_of(env)))
                  if isinstance(env, envs.LocomotionEnv) else saved_settings)
      if (mine, settings) != (saved["env"], saved_settings):
        given = mine + (f" {settings_text(settings)}" if mine == saved["env"] else "")
        raise ValueError(f"the checkpoint was trained on the task {saved['env']} "
                         f"{settings_text(saved_settings)}, not {given}")
      kwargs["env"] = task
    kwargs["train"] = TrainConfig(**saved["train"])
    kwargs["seeds"] = tuple(saved.get("seeds", ()))
    kwargs["grid"] = {k: tuple(v) for k, v in saved.get("grid", {}).items()}
    if saved.get("pbt") is not None:
      kwargs["pbt"] = PBT(**{**saved["pbt"], "factors": tuple(saved["pbt"]["factors"])})
    try:
      return cls(**kwargs)
    except ValueError as error:
      raise ValueError(_unreadable(saved, str(error))) from None


def _unreadable(saved: dict, why: str) -> str:
  """One line refusing a saved config that this version cannot read, saying why."""
  by = saved.get("versions", {}).get("mjx_hopper")
  by = f"mjx_hopper {by}" if by else "an older mjx_hopper"
  return (f"the saved config (checkpoint format {saved.get('checkpoint_format', 1)}, saved by "
          f"{by}) is not one mjx_hopper {mjx_hopper.__version__} reads: {why}; 0.x "
          "versions rename settings freely (CHANGELOG.md): use the version that saved it")


def load(path: str) -> "RunConfig":
  """The RunConfig saved in `path` (a run's config.json); anything else is a ValueError naming
  what is wrong."""
  try:
    with open(path) as f:
      saved = json.load(f)
  except (OSError, json.JSONDecodeError) as error:
    raise ValueError(f"--config {path}: cannot read it as JSON ({error})") from None
  if not isinstance(saved, dict) or not {"env", "agent", "train"} <= set(saved):
    raise ValueError(f"--config {path} is not a run's config.json (it lacks env, agent or "
                     "train)")
  try:
    return RunConfig.from_json(saved)
  except (TypeError, ValueError) as error:  # TypeError: an unknown setting of the trainer's
    raise ValueError(f"--config {path}: {error}") from None


def settings_table(cfg: RunConfig, flags: list, column: str) -> list[tuple[str, ...]]:
  """Rows of every setting of `cfg` (the run `flags`, then the agent's): its name, type,
  default, `cfg`'s value (headed `column`), and whether a sweep can vary it."""
  agent_cfg = cfg.agent_config()
  dynamic = set(dynamic_settings(cfg.agent, cfg.agent_defaults))
  rows = [("setting", "type", "default", column, "sweep")]
  for f in flags:
    now = getattr(cfg if hasattr(cfg, f.name) else cfg.train, f.name)
    rows.append(("--" + f.name.replace("_", "-"), str(f.type), repr(f.default), repr(now),
                 "yes" if f.name in dynamic else "no"))
  defaults = type(agent_cfg)()
  for f in dataclasses.fields(agent_cfg):
    rows.append((f"--set {f.name}=", str(f.type), repr(getattr(defaults, f.name)),
                 repr(getattr(agent_cfg, f.name)), "yes" if f.name in dynamic else "no"))
  return rows


def settings_text(settings: dict) -> str:
  """A task's settings, as '(episode_steps=300, height_weight=10.0)'."""
  return "(" + ", ".join(f"{k}={v!r}" for k, v in sorted(settings.items())) + ")"


def dynamic_settings(agent: str, agent_defaults: str = "cpu") -> list[str]:
  """The names a sweep's grid may vary for this agent."""
  return sorted(type(agents.config(agent, agent_defaults)).DYNAMIC + TRAINER_DYNAMIC)


def check_grid(agent: str, agent_defaults: str, grid: dict, train_cfg: TrainConfig,
               overrides: dict | None = None) -> None:
  """Raises ValueError naming the first bad entry of `grid` ({name: values}): an unknown or
  structural name, an empty or repeated list, or a value the config refuses."""
  cfg = agents.config(agent, agent_defaults, **(overrides or {}))
  fields = {f.name for f in dataclasses.fields(cfg)} | {
      f.name for f in dataclasses.fields(TrainConfig)}
  allowed = dynamic_settings(agent, agent_defaults)
  for name, values in grid.items():
    if name not in fields:
      raise ValueError(f"unknown setting {name!r} in the sweep; settings that can be swept are "
                       f"{allowed}")
    if name not in allowed:
      raise ValueError(f"{name!r} is structural (it shapes the compiled program) and cannot be "
                       f"swept in one program: run one sweep per value; settings that can be "
                       f"swept are {allowed}")
    if not isinstance(values, (list, tuple)) or not values:
      raise ValueError(f"the sweep's {name!r} needs a non-empty list of values, got {values!r}")
    if len(set(values)) != len(values):
      raise ValueError(f"the sweep's {name!r} repeats a value: {list(values)}")
    for value in values:
      check_value(agent, agent_defaults, name, value, train_cfg, overrides)


def check_value(agent: str, agent_defaults: str, name: str, value, train_cfg: TrainConfig,
                overrides: dict | None = None) -> None:
  """Raises ValueError when the dynamic setting `name` cannot take `value`."""
  if name in TRAINER_DYNAMIC:
    dataclasses.replace(train_cfg, **{name: value}).check()
  else:
    agents.config(agent, agent_defaults, **{**(overrides or {}), name: value})


def member_settings(seeds: tuple[int, ...], grid: dict) -> list[dict[str, Any]]:
  """Every member's seed and swept values, in member order: the grid's combinations in the
  order given (the last name varying fastest), each with every seed."""
  names = list(grid)
  return [{"seed": seed, **dict(zip(names, combo))}
          for combo in itertools.product(*(grid[n] for n in names)) for seed in seeds]


def field_defaults(config) -> dict:
  """A config dataclass's fields' default values."""
  return {f.name: f.default for f in dataclasses.fields(config)
          if f.default is not dataclasses.MISSING}
