"""The suite's training configurations, shared so that their programs are compiled once (in a
test worker's memory, `conftest.shared_builds`, and across workers and the processes tests
start, through the compile cache): each agent's tiny run on the Hopper, the notebook's short
mode (`notebook.tiny`), as a RunConfig and as the command line that makes the same run, and the
notebook's high jump. A test that trains picks one of these; a configuration of its own is an
exception, said where it is made."""

import dataclasses

from mjx_hopper import agents, envs
from mjx_hopper.envs.events import HighJump
from mjx_hopper.faces import notebook
from mjx_hopper.run import loop
from mjx_hopper.settings import presets

AGENTS = ("d4pg", "ddpg", "mpo", "dmpo")


def tiny(agent: str = "d4pg") -> loop.RunConfig:
  """`agent`'s tiny run on the Hopper over the CPU devices: 4 envs, 80 env steps of 30-step
  episodes, an evaluation of 2 episodes every 40 env steps, no time-based logging."""
  return dataclasses.replace(
      notebook.tiny(loop.RunConfig(env="Hopper", agent=agent, agent_defaults="cpu")), log_every=0.0)


def tiny_args(agent: str = "d4pg", command: str = "train") -> list[str]:
  """`tiny(agent)` on the command line of `mjx-hopper COMMAND` over 2 CPU devices, without its
  --total-env-steps (each test says its own)."""
  return args_of(tiny(agent), command)


def args_of(cfg: loop.RunConfig, command: str = "train") -> list[str]:
  """A tiny run `cfg` (`notebook.tiny`'s sizes, the cpu preset) on the command line of
  `mjx-hopper COMMAND` over 2 CPU devices, without its --total-env-steps."""
  t, agent = notebook.TINY_TRAIN, cfg.agent
  assert cfg.train == t and cfg.agent_defaults == "cpu", "args_of takes a tiny run"
  # The tiny settings, and the robot's cpu preset's others back at the agent's defaults, as
  # notebook.tiny has them.
  preset = presets.agent_run_config(cfg.env, "cpu", agent).agent_overrides
  chosen = dataclasses.asdict(cfg.agent_config())
  sets = [f"{name}={chosen[name]!r}" for name in {**preset, **agents.spec(agent).tiny}]
  task = envs.task_id(envs.task_class(cfg.env))
  return ["--cpu-devices", "2", command, "--env", task, "--agent", agent, "--preset", "cpu",
          *[arg for s in sets for arg in ("--set", s.replace(" ", ""))],
          *[arg for k, v in cfg.env_settings.items() for arg in ("--env-set", f"{k}={v!r}")],
          "--num-envs", str(t.num_envs), "--unroll-length", str(t.unroll_length),
          "--batch-size", str(t.batch_size), "--replay-ratio", f"{t.replay_ratio:g}",
          "--replay-size", str(t.replay_size), "--min-replay", str(t.min_replay),
          "--iterations-per-chunk", str(t.iterations_per_chunk),
          "--episode-steps", str(cfg.episode_steps), "--eval-episodes", str(cfg.eval_episodes),
          "--eval-every", str(cfg.eval_every), "--no-progress", "--log-every", "0"]


TINY = tiny("d4pg")
TINY_ARGS = tiny_args("d4pg")
# The notebook's tiny D4PG run on its high jump, its setting given: the programs of the
# notebook's own high jump (a class of its own, which lowers to the same programs).
JUMP = dataclasses.replace(
    notebook.tiny(presets.agent_run_config(HighJump, "cpu", "d4pg",
                                           env_settings={"height_weight": 10.0})),
    log_every=0.0)
JUMP_ARGS = args_of(JUMP)
# Four members of it, two seeds by two sigmas: the programs of the notebook's population (its
# PBT cell), as of any four members of it whatever their seeds and swept values.
POPULATION = dataclasses.replace(JUMP, seeds=(0, 1), grid={"sigma": (0.1, 0.3)})
