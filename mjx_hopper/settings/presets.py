"""Per-robot settings, chosen by measurement: for each robot a `cpu` and a `gpu` preset of the
agent, its settings, the trainer's layout and how long to train. Each `why` names the commit
holding its evidence.

    from mjx_hopper.run import loop
    from mjx_hopper.settings import presets
    cfg = presets.run_config("Walker2D", "gpu")   # trains long enough to reach its target
    loop.run(cfg)

`mjx-hopper train --env Walker2D --preset gpu` starts from the same settings.
"""

from __future__ import annotations

import dataclasses
import warnings

from mjx_hopper import envs
from mjx_hopper.settings.config import RunConfig
from mjx_hopper.settings.training import TrainConfig

KINDS = ("gpu", "cpu")


@dataclasses.dataclass(frozen=True)
class Preset:
  """A robot's measured settings for one kind of machine: its agent, trainer layout,
  evaluation period, its score, and the budget that reaches it. Its agent's settings are the
  agent's own defaults of the same kind, with `agent_overrides` over them."""

  agent: str
  agent_overrides: dict
  train: TrainConfig
  eval_every: int           # env steps between evaluations
  target: float | None      # the evaluation return that counts as solved (None: unmeasured)
  env_steps: int            # a run's budget in env steps and in minutes (compile included):
  minutes: float            # whichever comes first ends it
  why: str                  # one line: the choice, and the commit holding its evidence


# A preset's target is the score of its time-to-score results behind the README's table
# (benchmarks/report.py's GPU and CPU files), and its budget 1.5 times what the slowest of those
# seeds needed to reach it, rounded up (report.budget); tests/test_presets.py holds both to them.


# D4PG's cpu defaults and the trainer's default layout: a few hundred envs, small batches.
_CPU = dict(agent="d4pg", agent_overrides={}, train=TrainConfig(),
            eval_every=200_000)
# The Hopper's own D4PG settings: a penalty on the squared pre-tanh actions keeps the policy off
# the tanh's limits early on, which lets it learn at a higher rate, with mixed exploration noise
# (stds spread over the envs).
_HOPPER_CPU = {"action_penalty": 0.1, "learning_rate": 2e-3, "sigma": 0.4, "sigma_min": 0.05}
_SMALL_NETWORKS = {"policy_layers": (128, 128), "critic_layers": (128, 128)}
_CPU_TUNED = {**_CPU, "agent_overrides": {**_HOPPER_CPU, **_SMALL_NETWORKS}}

# One GPU: few envs and many updates (FastTD3's layout): 1,024 envs stepped once per iteration
# feed 8 updates of 8,192 transitions, with mixed noise.
_GPU_TRAIN = TrainConfig(num_envs=1024, unroll_length=1, batch_size=8192,
                               replay_ratio=64.0, replay_size=4_000_000, min_replay=40_960,
                               iterations_per_chunk=50)
_GPU = dict(agent="d4pg", agent_overrides={"sigma": 0.4, "sigma_min": 0.05},
            train=_GPU_TRAIN, eval_every=500_000)
_GPU_WHY = "1,024 envs, 8 updates of 8,192 per iteration, mixed noise (evidence: 60e8b34)"
_CPU_TUNED_WHY = "Hopper's cpu settings, 128-128 networks (evidence: {})"

PRESETS: dict[tuple[str, str], Preset] = {
    ("Hopper", "cpu"): Preset(**_CPU_TUNED, target=2000.0, env_steps=4_000_000, minutes=8.0,
                              why=_CPU_TUNED_WHY.format("e19d40f")),
    ("Hopper", "gpu"): Preset(**{**_GPU, "agent_overrides": {**_GPU["agent_overrides"],
                                                             "action_penalty": 0.1,
                                                             "learning_rate": 1e-3,
                                                             "compute_dtype": "bfloat16"}},
                              target=2500.0, env_steps=5_500_000, minutes=2.0,
                              why="the gpu layout, action penalty, 1e-3, bfloat16 hidden layers "
                                  "(evidence: 275635e)"),
    ("Walker2D", "cpu"): Preset(**_CPU_TUNED, target=2000.0, env_steps=6_500_000, minutes=6.0,
                                why=_CPU_TUNED_WHY.format("9d394f9")),
    ("Walker2D", "gpu"): Preset(**_GPU, target=2500.0, env_steps=23_000_000, minutes=5.0,
                                why=_GPU_WHY),
    ("HalfCheetah", "cpu"): Preset(**_CPU, target=3000.0, env_steps=21_500_000, minutes=50.0,
                                   why="D4PG's cpu preset: the Hopper's settings left it standing "
                                       "(evidence: 0925ba5)"),
    # Wider noise and smaller, more numerous batches at the same replay ratio.
    ("HalfCheetah", "gpu"): Preset(**{
        **_GPU, "agent_overrides": {"sigma": 0.6, "sigma_min": 0.2, "learning_rate": 1e-3},
        "train": dataclasses.replace(_GPU_TRAIN, num_envs=512, batch_size=1024,
                                     replay_size=1_000_000),
        "eval_every": 250_000}, target=3000.0, env_steps=4_000_000, minutes=3.0,
        why="512 envs, 32 updates of 1,024, 1e-3, noise 0.2 to 0.6 (evidence: 60e8b34)"),
    ("Ant", "cpu"): Preset(**_CPU_TUNED, target=3000.0, env_steps=8_500_000, minutes=18.0,
                           why=_CPU_TUNED_WHY.format("9ac1947")),
    ("Ant", "gpu"): Preset(**_GPU, target=3000.0, env_steps=12_500_000, minutes=3.0,
                           why=_GPU_WHY),
    ("Humanoid", "cpu"): Preset(**_CPU_TUNED, target=2500.0, env_steps=12_500_000, minutes=38.0,
                                why=_CPU_TUNED_WHY.format("6ae7853")),
    ("Humanoid", "gpu"): Preset(**{**_GPU, "agent_overrides": {
        **_GPU["agent_overrides"], "critic_layers": (1024, 512, 256),
        "policy_layers": (512, 256, 128)}}, target=2500.0, env_steps=11_500_000, minutes=5.0,
        why="the gpu layout with FastTD3's larger networks (evidence: 60e8b34)"),
}


# The events (envs/events.py) measured on their own task, by task id: their robot's preset with
# their own agent settings, score and budget. Another task takes its robot's preset.
TASK_PRESETS: dict[tuple[str, str], Preset] = {
    ("mjx_hopper.envs.events:HighJump", "cpu"): Preset(**{
        **_CPU_TUNED, "agent_overrides": {**_CPU_TUNED["agent_overrides"], "vmax": 900.0}},
        target=1500.0, env_steps=4_000_000, minutes=8.0,
        why="Hopper's cpu settings, a critic's support to 900 for the jump's larger returns "
            "(evidence: a552af9)"),
    ("mjx_hopper.envs.events:AntLongJump", "gpu"): Preset(
        **_GPU, target=3000.0, env_steps=8_000_000, minutes=3.0,
        why="the Ant's gpu preset, its budget measured on the jump (evidence: 6c6fa7b)"),
}


# A robot of one's own, with no measured preset: D4PG's defaults of the kind with its trainer
# layout, RunConfig's budget, no score.
UNMEASURED = {kind: Preset(**settings, target=None, env_steps=RunConfig.total_env_steps,
                           minutes=None, why="no preset is measured for this robot")
              for kind, settings in (("cpu", _CPU), ("gpu", _GPU))}


def get(env, kind: str) -> Preset:
  """The preset for `kind` ("gpu" or "cpu") of robot `env`, of the event `env` where measured
  (`TASK_PRESETS`), else of the robot that the task `env` (a class, an instance or a
  `module:Class` path) subclasses; `UNMEASURED`'s for a robot of one's own."""
  cls = envs.task_class(env)
  if kind not in KINDS:
    raise ValueError(f"unknown robot preset {kind!r}; valid presets are {list(KINDS)}")
  measured = TASK_PRESETS.get((envs.task_id(cls), kind))
  return measured or PRESETS.get((envs.robot_of(cls), kind), UNMEASURED[kind])


# Other agents' settings on a robot where they were measured, over the agent's own defaults.
AGENT_OVERRIDES: dict[tuple[str, str, str], dict] = {
    ("Hopper", "cpu", "ddpg"): _HOPPER_CPU,  # evidence: 2c5cb5a
    ("Hopper", "cpu", "dmpo"): {"learning_rate": 1e-3, **_SMALL_NETWORKS},  # evidence: d3c32d9
}
# Their budgets, (env steps, minutes), where measured, as the robots' are (report.budget); the
# robot preset's target is theirs too.
AGENT_BUDGETS: dict[tuple[str, str, str], tuple[int, float]] = {
    ("Hopper", "cpu", "ddpg"): (4_000_000, 10.0),
    ("Hopper", "cpu", "dmpo"): (7_000_000, 22.0),
}


def agent_run_config(env, kind: str, agent: str, *, warn: bool = True, **changes):
  """The RunConfig of `agent` on robot or task `env` with its `kind` settings: the
  robot's preset when it is one of this agent, else the agent's own defaults of that name with
  the trainer's and the robot's settings for this agent (`AGENT_OVERRIDES`); fields
  replaced by `changes` as in `run_config`, which says how `warn` works."""
  robot = envs.robot_of(envs.task_class(env))
  if get(env, kind).agent == agent:
    return run_config(env, kind, warn=warn, **changes)
  if warn:
    _warn_if_unmeasured(env, kind, agent, changes)
  overrides = {**AGENT_OVERRIDES.get((robot, kind, agent), {}),
               **changes.pop("agent_overrides", {})}
  if (robot, kind, agent) in AGENT_BUDGETS and "total_env_steps" not in changes:
    steps, minutes = AGENT_BUDGETS[robot, kind, agent]
    changes = {"total_env_steps": steps, "max_minutes": minutes, **changes}
  return RunConfig(env=env, agent=agent, agent_defaults=kind, agent_overrides=overrides,
                   **changes)


def unmeasured_budget(env, kind: str, agent: str) -> str | None:
  """A line for a run whose budget was not measured to reach a score (None where it was): an
  agent other than the robot's with no budget of its own (`AGENT_BUDGETS`), or a task of your
  own, which takes its robot's."""
  cls = envs.task_class(env)
  robot, name = envs.robot_of(cls), envs.task_id(cls)
  if (robot, kind) not in PRESETS:
    return (f"no preset is measured for {robot} ({kind}): it trains {agent} with its {kind} "
            f"settings for {RunConfig.total_env_steps:,} env steps, RunConfig's default, which "
            "may not reach a score; set --total-env-steps or --max-minutes")
  if get(cls, kind).agent != agent and (robot, kind, agent) not in AGENT_BUDGETS:
    return (f"no budget is measured for {agent} on {robot} ({kind}): it trains "
            f"{RunConfig.total_env_steps:,} env steps, RunConfig's default, which may not reach "
            "a score; set --total-env-steps or --max-minutes")
  if name != robot and (name, kind) not in TASK_PRESETS:
    return (f"{name} trains for its robot's budget ({robot}'s {kind} preset), measured on "
            f"{robot}'s own task; set --total-env-steps or --max-minutes to choose another")
  return None


def _warn_if_unmeasured(env, kind: str, agent: str, changes: dict) -> None:
  """Warns with `unmeasured_budget`'s line where `changes` give no budget of their own."""
  if not {"total_env_steps", "max_minutes"} & changes.keys():
    if line := unmeasured_budget(env, kind, agent):
      warnings.warn(line, stacklevel=3)


def run_config(env, kind: str, *, warn: bool = True, **changes):
  """The RunConfig of robot `env`'s `kind` preset, budget included, with fields replaced by
  `changes` (agent_overrides are merged into the preset's; `train` replaces its TrainConfig).
  A `total_env_steps` given without `max_minutes` replaces the whole budget. For a task of your
  own (a subclass of a robot), the preset is its robot's; for an event, its own where measured.
  Where no run measured the budget it gives, it warns with `unmeasured_budget`'s line, unless
  `warn` is False (the CLI, which says it itself once its flags are read)."""
  preset = get(env, kind)
  if warn:
    _warn_if_unmeasured(env, kind, preset.agent, changes)
  if "total_env_steps" in changes:
    changes.setdefault("max_minutes", None)
  overrides = {**preset.agent_overrides, **changes.pop("agent_overrides", {})}
  return RunConfig(**{
      "env": env, "agent": preset.agent, "agent_defaults": kind,
      "agent_overrides": overrides, "train": preset.train, "eval_every": preset.eval_every,
      "total_env_steps": preset.env_steps, "max_minutes": preset.minutes, **changes})
