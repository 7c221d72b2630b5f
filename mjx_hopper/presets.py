"""Per-robot settings, chosen by measurement: for each robot, a `gpu` and a `cpu` preset of the
agent, its settings and the trainer's layout. BENCHMARKS.md ("Every robot, time to score") has
what each reaches, and docs/benchmark-history.md ("The GPU presets") the runs behind them.

    from mjx_hopper import loop, presets
    cfg = presets.run_config("Walker2D", "gpu", max_minutes=5)
    loop.run(cfg)

`mjx-hopper train --env Walker2D --preset gpu` starts from the same settings; its flags and
`--set` replace any of them.
"""

from __future__ import annotations

import dataclasses

from mjx_hopper import envs, train

KINDS = ("gpu", "cpu")


@dataclasses.dataclass(frozen=True)
class Preset:
  agent: str                # the agent, with its named preset and overrides
  agent_preset: str
  agent_overrides: dict
  train: train.TrainConfig
  eval_every: int           # env steps between evaluations
  target: float             # the evaluation return that counts as solved (issue 15's targets)
  minutes: float            # the time budget of benchmarks/time_to_score.py
  why: str                  # the measurement behind it, in a sentence


# The 2-core CPU: TrainConfig's defaults and D4PG's cpu preset, which reached 2,000 on Hopper in
# the fewest CPU-affordable env steps and updates (docs/benchmark-history.md, "Choosing the CPU
# settings"). HalfCheetah runs it as it is: the Hopper's settings below left its seeds standing.
_CPU = dict(agent="d4pg", agent_preset="cpu", agent_overrides={}, train=train.TrainConfig(),
            eval_every=200_000)
_CPU_UNTUNED = "D4PG's cpu preset and layout, not tuned for this robot"
# The Hopper's own: a penalty of 0.1 on the squared pre-tanh actions, so that the policy is not
# pinned at the tanh's limits early on (seed 0 of the cpu preset was, for its first 500k env
# steps), which let it learn at 2e-3 with mixed noise: 1.80M env steps to 2,000 on average over
# 12 seeds, against the preset's 3.98M over 4 (screened on an H100; BENCHMARKS.md "On the
# 2-core CPU").
_HOPPER_CPU = {"action_penalty": 0.1, "learning_rate": 2e-3, "sigma": 0.4, "sigma_min": 0.05}
# D4PG's networks on Hopper are 128-128 (the cpu preset's 256-256 halved): 1.53x the updates/s
# on 2 cores, and over seeds 0-4 on 2 cores 2,000 at 134-198 s, median 156, against 164-244 s,
# median 197, in the same session, each seed faster; in 2.00M env steps on average against 1.86M
# (BENCHMARKS.md, "On the 2-core CPU"). DDPG keeps 256-256, as measured. Walker2D, the Ant and
# the Humanoid learn sooner with all of it too; HalfCheetah did not (its seeds stood still, as
# with mixed noise before).
_SMALL_NETWORKS = {"policy_layers": (128, 128), "critic_layers": (128, 128)}
_TUNED_CPU_D4PG = {**_HOPPER_CPU, **_SMALL_NETWORKS}
_CPU_TUNED = {**_CPU, "agent_overrides": _TUNED_CPU_D4PG}
_TUNED_CPU_WHY = ("Hopper's cpu settings (128-128 networks, action penalty 0.1, learning rate "
                  "2e-3, mixed noise 0.05 to 0.4)")

# One GPU: few envs and many updates. 1,024 envs stepped once per iteration feed 8 updates of
# 8,192 transitions (replay ratio 64, FastTD3's layout), and the envs explore at stds spread
# from 0.05 to 0.4 (mixed noise). Screened on one H100 (docs/benchmark-history.md, "The GPU
# presets"): on Hopper this layout passed 2,000 in 1.7M env steps where 512 envs x unroll 4 with
# 8 updates of 1,024 needed 4.4M, and on the Humanoid it learned (390 in 3M env steps) where
# 4,096 envs with 2 updates of 32,768 did not (94 in 12M). Clipped double Q (num_critics=2) is
# left off: it slowed Hopper (117 against 635 in the same 3 minutes) and the Humanoid (336
# against 390). Alone on an H100 they passed every target but Hopper's 90 s (BENCHMARKS.md).
_GPU_TRAIN = train.TrainConfig(num_envs=1024, unroll_length=1, batch_size=8192,
                               replay_ratio=64.0, replay_size=4_000_000, min_replay=40_960,
                               iterations_per_chunk=50)
_GPU = dict(agent="d4pg", agent_preset="gpu", agent_overrides={"sigma": 0.4, "sigma_min": 0.05},
            train=_GPU_TRAIN, eval_every=500_000)
_GPU_WHY = ("1,024 envs, 8 updates of 8,192 per iteration (ratio 64), mixed noise 0.05 to "
            "0.4: the fastest-learning layout of the H100 screens, on Hopper and the Humanoid")

PRESETS: dict[tuple[str, str], Preset] = {
    ("Hopper", "cpu"): Preset(**_CPU_TUNED, target=2000.0, minutes=5.0, why=(
        "D4PG cpu preset with 128-128 networks, 512 envs, batch 256, replay ratio 4, with an "
        "action penalty of 0.1, learning rate 2e-3 and mixed noise 0.05 to 0.4: 2,000 on 2 "
        "cores at 134-198 s, median 156, for seeds 0-4, each compiled afresh")),
    # With a penalty of 0.1 on the squared pre-tanh actions: over ten runs of seeds 0-4 each, it
    # needed 0.79x the env steps to 2,500 (3.36M against 4.25M on average; 9 of 10 reached it
    # either way); without it, two seeds of five had their policy pinned at the tanh's limits
    # for 300k to 700k env steps. With the penalty the learning rate could rise: at 1e-3 seeds
    # 0-9 needed 1.94M env steps on average, all ten reaching 2,500, against 3.03M for seeds 0-4
    # at 3e-4; at 2e-3 two of five fell short of it in 6M. The networks compute in bfloat16:
    # 1.29x the env steps/s alone on an H100 (the updates fill the learner), and seeds 0-4
    # needed 2.14M env steps to 2,500 on average against float32's 1.94M. The policy learning
    # at every second update (policy_every=2) ran 1.13-1.16x the env steps/s but needed 1.13x
    # the env steps on average over 19 runs, so no sooner to 2,500 (BENCHMARKS.md, "Learning,
    # per agent"): not taken.
    ("Hopper", "gpu"): Preset(**{**_GPU, "agent_overrides": {**_GPU["agent_overrides"],
                                                             "action_penalty": 0.1,
                                                             "learning_rate": 1e-3,
                                                             "compute_dtype": "bfloat16"}},
                              target=2500.0, minutes=1.5, why=(
        _GPU_WHY + "; for Hopper with an action penalty of 0.1, learning rate 1e-3 and "
        "bfloat16 hidden layers: 0.64x the env steps to 2,500 of the penalty alone, at 1.29x "
        "the env steps/s")),
    # Hopper's D4PG settings, 128-128 networks included: screened on an H100 in this layout,
    # seeds 0-3 passed 2,000 in 3.02M to 4.40M env steps (mean 3.52M; 2,500 on 3 of 4 by 7.4M),
    # against 5.02M to 6.25M (mean 5.53M; 2,500 on none) with D4PG's cpu preset as it is, in the
    # same run; with 256-256 networks 2.61M to 3.84M (mean 3.23M), but 128-128 runs 1.35x the
    # env steps/s on 2 cores. There seeds 0-4 passed 2,000 at 199 to 355 s, median 283, where the
    # preset as it was took 10.1 minutes (seed 0; BENCHMARKS.md, "On the 2-core CPU").
    ("Walker2D", "cpu"): Preset(**_CPU_TUNED, target=2500.0, minutes=60.0, why=(
        _TUNED_CPU_WHY + ": 2,000 in 0.64x the env steps of D4PG's cpu preset (four seeds "
        "screened on a GPU), and on 2 cores at 199 to 355 s, median 283, for seeds 0-4")),
    ("Walker2D", "gpu"): Preset(**_GPU, target=2500.0, minutes=4.0, why=_GPU_WHY),
    ("HalfCheetah", "cpu"): Preset(**_CPU, target=3000.0, minutes=60.0, why=(
        _CPU_UNTUNED + "; on 2 cores it passed 3,000 in 19.1 minutes (one seed), and mixed "
        "noise did no better in emulation")),
    # Wider noise, stds from 0.2 to 0.6: with 0.05 to 0.4, two seeds of three stood still (about
    # 1,000) for 12M and 17.5M env steps; with 0.2 to 0.6 all three passed 3,000 by 9.0M. Then
    # smaller batches, more of them: 512 envs feeding 32 updates of 1,024 (the same ratio 64) at
    # learning rate 1e-3 passed 3,000 in 1.25M to 2.05M env steps, 68 to 109 s, on five seeds of
    # five (a 16-member grid had shown it: BENCHMARKS.md, "Population-based training").
    ("HalfCheetah", "gpu"): Preset(**{
        **_GPU, "agent_overrides": {"sigma": 0.6, "sigma_min": 0.2, "learning_rate": 1e-3},
        "train": dataclasses.replace(_GPU_TRAIN, num_envs=512, batch_size=1024,
                                     replay_size=1_000_000),
        "eval_every": 250_000}, target=3000.0, minutes=5.0, why=(
        "512 envs, 32 updates of 1,024 per iteration (ratio 64), learning rate 1e-3, mixed noise "
        "0.2 to 0.6: 3,000 in 1.25M to 2.05M env steps on five seeds, against 7M to 9M with the "
        "other robots' 8 updates of 8,192")),
    # Hopper's cpu settings: screened on an H100 in this layout, seeds 0-3 passed 2,000 in 1.84M
    # to 3.02M env steps (mean 2.37M) and 2,500 in 3.23M to 4.61M (mean 3.83M), against 3.02M to
    # 3.43M (3.23M) and 3.84M to 5.02M (4.53M) with D4PG's cpu preset, in the same run. On 2
    # cores seed 0 passed 3,000 at 12.3 minutes (7.63M env steps), against 18.7 (7.83M) before:
    # its 128-128 networks run about 11,000 env steps/s against 7,500.
    ("Ant", "cpu"): Preset(**_CPU_TUNED, target=3000.0, minutes=60.0, why=(
        _TUNED_CPU_WHY + ": 2,500 in 0.85x the env steps of D4PG's cpu preset (four seeds "
        "screened on a GPU), and 3,000 on 2 cores at 12.3 minutes, against 18.7 (seed 0)")),
    ("Ant", "gpu"): Preset(**_GPU, target=3000.0, minutes=5.0, why=_GPU_WHY),
    # Hopper's cpu settings: on 2 cores seeds 0 and 1 passed 2,500 at 13.2 and 16.7 minutes (5.02M
    # and 6.25M env steps), where D4PG's cpu preset took 21.5 (seed 0, 6.60M); 128-128 networks
    # run about 6,800 env steps/s against 5,400. Only two seeds: its GPU screen, in this layout,
    # steps slower than the 2-core CPU.
    ("Humanoid", "cpu"): Preset(**_CPU_TUNED, target=2500.0, minutes=60.0, why=(
        _TUNED_CPU_WHY + ": 2,500 on 2 cores at 13.2 and 16.7 minutes (seeds 0 and 1), against "
        "21.5 with D4PG's cpu preset (seed 0)")),
    # FastTD3's larger networks: 468 against 390 in the same 7 minutes of the screen (one seed).
    ("Humanoid", "gpu"): Preset(**{**_GPU, "agent_overrides": {
        **_GPU["agent_overrides"], "critic_layers": (1024, 512, 256),
        "policy_layers": (512, 256, 128)}}, target=2500.0, minutes=15.0,
        why=_GPU_WHY + "; larger networks (critic 1,024-512-256, policy 512-256-128)"),
}


def get(env, kind: str) -> Preset:
  """The preset for `kind` ("gpu" or "cpu") of robot `env`, or of the robot that the task `env`
  (a class, an instance or a `module:Class` path) subclasses."""
  robot = envs.robot_of(envs.task_class(env))
  if kind not in KINDS:
    raise ValueError(f"unknown robot preset {kind!r}; valid presets are {list(KINDS)}")
  return PRESETS[robot, kind]


# The other agents' settings on a robot where they were measured, over the agent's own preset of
# that name and the trainer's defaults. DDPG on Hopper takes the Hopper's D4PG settings (the
# action penalty, learning rate 2e-3, mixed noise): 2,000 in 1.02M to 3.02M env steps on seeds
# 0-4 screened on an H200 in the cpu layout, and in 104-263 s on 2 cores (seeds 0-4, median
# 176), where it took 9 to 17 minutes before (BENCHMARKS.md, "Learning, per agent"). DMPO on
# Hopper learns at 1e-3 instead of 3e-4: on 2 cores, seeds 0-2 passed 2,000 at 842, 529 and
# 831 s (3e-4: 688, 802 and 897, the last 3 s inside the notebook's 15-minute cell); on H200s in
# the cpu layout, seeds 0-4 in 2.82M to 3.43M env steps (3e-4: seed 0 not in 4.1M). Its networks
# are 128-128, as D4PG's: its update scores 20 sampled actions per state, and runs 1.59x the
# updates/s on 2 cores; seed 0 passed 2,000 at 500 s (4.04M env steps) against 842, and seeds
# 0-2 trained at once in 2.61M, 3.43M and 4.04M env steps (BENCHMARKS.md, "Learning, per agent").
AGENT_OVERRIDES: dict[tuple[str, str, str], dict] = {
    ("Hopper", "cpu", "ddpg"): _HOPPER_CPU,
    ("Hopper", "cpu", "dmpo"): {"learning_rate": 1e-3, **_SMALL_NETWORKS},
}


def agent_run_config(env, kind: str, agent: str, **changes):
  """The `loop.RunConfig` of `agent` on robot or task `env` with its `kind` settings: the
  robot's preset when it is one of this agent, else the agent's own preset of that name with
  the trainer's defaults and the robot's settings for this agent (`AGENT_OVERRIDES`); fields
  replaced by `changes` as in `run_config`."""
  robot = envs.robot_of(envs.task_class(env))
  preset = PRESETS.get((robot, kind))
  if preset is not None and preset.agent == agent:
    return run_config(env, kind, **changes)
  from mjx_hopper import loop
  overrides = {**AGENT_OVERRIDES.get((robot, kind, agent), {}),
               **changes.pop("agent_overrides", {})}
  return loop.RunConfig(env=env, agent=agent, preset=kind, agent_overrides=overrides, **changes)


def run_config(env, kind: str, **changes):
  """The `loop.RunConfig` of robot `env`'s `kind` preset, with fields replaced by `changes`
  (agent_overrides are merged into the preset's; `train` replaces its TrainConfig). For a task
  of your own (a subclass of a robot), the preset is its robot's."""
  from mjx_hopper import loop
  preset = get(env, kind)
  overrides = {**preset.agent_overrides, **changes.pop("agent_overrides", {})}
  return loop.RunConfig(**{
      "env": env, "agent": preset.agent, "preset": preset.agent_preset,
      "agent_overrides": overrides, "train": preset.train, "eval_every": preset.eval_every,
      **changes})
