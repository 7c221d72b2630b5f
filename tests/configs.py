"""The suite's training configurations, shared so that their programs are compiled once (in a
test worker's memory, `conftest.shared_builds`, and across workers and the processes tests
start, through the compile cache): each agent's tiny run on the Hopper, the notebook's short
mode (`notebook.tiny`), as a RunConfig and as the command line that makes the same run, and the
notebook's high jump. A test that trains picks one of these; a configuration of its own is an
exception, said where it is made."""

import dataclasses

from mjx_hopper import agents
from mjx_hopper.envs.events import HighJump
from mjx_hopper.faces import notebook
from mjx_hopper.run import loop
from mjx_hopper.settings import presets

AGENTS = ("d4pg", "ddpg", "mpo", "dmpo")


def tiny(agent: str = "d4pg") -> loop.RunConfig:
  """`agent`'s tiny run on the Hopper over the CPU devices: 4 envs, 80 env steps of 30-step
  episodes, an evaluation of 2 episodes every 40 env steps, no time-based logging."""
  return dataclasses.replace(
      notebook.tiny(loop.RunConfig(env="Hopper", agent=agent, agent_preset="cpu")), log_every=0.0)


def tiny_args(agent: str = "d4pg", command: str = "train") -> list[str]:
  """`tiny(agent)` on the command line of `mjx-hopper COMMAND` over 2 CPU devices, without its
  --total-env-steps (each test says its own)."""
  cfg, t = tiny(agent), notebook.TINY_TRAIN
  # The tiny settings, and the robot's cpu preset's others back at the agent's defaults, as
  # notebook.tiny has them.
  preset = presets.agent_run_config(cfg.env, "cpu", agent).agent_overrides
  chosen = dataclasses.asdict(cfg.agent_config())
  sets = [f"{name}={chosen[name]!r}" for name in {**preset, **agents.spec(agent).tiny}]
  return ["--cpu-devices", "2", command, "--env", cfg.env, "--agent", agent, "--preset", "cpu",
          *[arg for s in sets for arg in ("--set", s.replace(" ", ""))],
          "--num-envs", str(t.num_envs), "--unroll-length", str(t.unroll_length),
          "--batch-size", str(t.batch_size), "--replay-ratio", f"{t.replay_ratio:g}",
          "--replay-size", str(t.replay_size), "--min-replay", str(t.min_replay),
          "--iterations-per-chunk", str(t.iterations_per_chunk),
          "--episode-steps", str(cfg.episode_steps), "--eval-episodes", str(cfg.eval_episodes),
          "--eval-every", str(cfg.eval_every), "--no-progress", "--log-every", "0"]


TINY = tiny("d4pg")
TINY_ARGS = tiny_args("d4pg")
# The notebook's tiny D4PG run on its high jump, its setting given: the programs of the
# notebook's own high jump (a class of its own, which lowers to the same programs), and those of
# its population (PBT) where a test trains four members of it.
JUMP = dataclasses.replace(
    notebook.tiny(presets.agent_run_config(HighJump, "cpu", "d4pg",
                                           env_settings={"height_weight": 10.0})),
    log_every=0.0)
