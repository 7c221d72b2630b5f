"""Making a run's trainer and state, and getting a saved run back: `restore` (the whole state),
`load_policy` (one member's agent) and `extract` (one member of a sweep as a single run).
`loop.resume` goes on training one."""

from __future__ import annotations

import dataclasses
import json
import os
from typing import Any

import jax
import numpy as np

from mjx_hopper import agents, checkpoint, envs, train
from mjx_hopper.config import TRAINER_DYNAMIC, RunConfig


def build(cfg: RunConfig, num_members: int | None = None) -> train.Trainer:
  """The compiled trainer of `cfg`'s members (or of `num_members` of them), after checking its
  task's reward."""
  env = cfg.make_env()
  envs.check_task(env)
  agent = agents.make(cfg.agent, env.observation_size, env.action_size, cfg.agent_config())
  return train.make_trainer(env, agent, cfg.train_config(), eval_episodes=cfg.eval_episodes,
                            num_members=num_members or len(cfg.members()),
                            dynamic_updates="replay_ratio" in cfg.grid)


def init(cfg: RunConfig, trainer: train.Trainer, members: list[dict]) -> train.TrainState:
  """The fresh TrainState of `members` (from `cfg.members()`), each from its own seed's key and
  with its own swept values: a member starts as the single run of its settings."""
  return trainer.init([m["seed"] for m in members],
                      {name: [m[name] for m in members] for name in cfg.grid})


def check_which(which: str) -> None:
  """Raises ValueError unless `which` names the best evaluation's agent or the latest."""
  if which not in ("best", "latest"):
    raise ValueError(f"which must be 'best' or 'latest', got {which!r}")


def restore(directory: str, print_fn=print, env: Any = None):
  """(RunConfig, TrainState, Trainer) of the newest readable checkpoint in `directory`, replay
  included: after a Colab restart, the one call that gets a run back. `env` is the run's task,
  for one that cannot be imported (defined in a notebook)."""
  return _restore(directory, print_fn, env)[:3]


def saved_config(directory: str, print_fn=print, env: Any = None) -> RunConfig:
  """The RunConfig of the newest readable checkpoint in `directory`; `env` as in `restore`."""
  mngr = open_checkpoints(directory)
  return checkpoint.load_newest(mngr, lambda step: _saved_run(mngr, step, env)[0], print_fn)[1]


def load_policy(directory: str, member: int | str = 0, env: Any = None, which: str = "best",
                print_fn=print):
  """(RunConfig, agent state, Trainer) of the newest readable checkpoint in `directory`: the
  agent of the member at position `member` (or "best": the member of the best evaluation)
  without the member axis, at its best evaluation (or which="latest"), read without the
  replay. Says which policy it loaded."""
  check_which(which)
  mngr = open_checkpoints(directory)

  def load(step):
    cfg, members, saved = _saved_run(mngr, step, env)
    position = _position(directory, saved, member)
    if not 0 <= position < len(members):
      raise checkpoint.ConfigMismatch(f"member {position} is not in {directory}: it holds "
                                      f"{len(members)} member(s), 0 to {len(members) - 1}")
    trainer = build(cfg, len(members))
    like = jax.eval_shape(lambda k: init(cfg, trainer, members).agent, 0)
    best = which == "best" and checkpoint.has_best(mngr, step)
    agent_state = checkpoint.restore_agent(mngr, step, like, "best" if best else "agent")
    record = saved.get("record", {})
    score = record.get("best_return", [None] * len(members))[position] if best else None
    if score is not None:
      print_fn(f"the policy of its best evaluation: return {score:.1f} at "
               f"{record['best_env_steps'][position]:,} env steps")
    elif best:
      print_fn("the policy of its first evaluation (none of its evaluations was finite)")
    else:
      print_fn(f"the latest policy, at {step * trainer.config.steps_per_iteration:,} env steps"
               + ("" if which == "latest" else " (no evaluation was saved yet)"))
    return cfg, jax.tree.map(lambda x: x[position], agent_state), trainer

  return checkpoint.load_newest(mngr, load)[1]


def evaluate_checkpoint(directory: str, member: int | str = 0, episodes: int = 16,
                        seed: int = 0, video_path: str | None = None, which: str = "best",
                        env: Any = None, print_fn=print) -> dict:
  """Evaluates a checkpoint's policy (as `load_policy` picks it) over `episodes` episodes, and
  with `video_path`, films episode 0 as an mp4. Returns the per-episode "return" and "length"."""
  cfg, agent_state, trainer = load_policy(directory, member, env, which, print_fn)
  result = jax.device_get(jax.jit(lambda s, k: train.evaluate(
      trainer.env, trainer.agent, s, k, episodes, record_qpos=video_path is not None))(
          agent_state, jax.random.PRNGKey(seed)))
  returns = np.asarray(result["return"])
  print_fn(f"{cfg.task_id} / {cfg.agent}: return {returns.mean():.1f} +- {returns.std():.1f}, "
           f"length {np.mean(result['length']):.0f} over {episodes} episodes")
  if video_path is not None:
    from mjx_hopper.envs import render
    length = int(result["length"][0])
    qpos = np.asarray(result.pop("qpos")[:length + 1])
    frames = render.render_frames(trainer.env.mj_model, qpos)
    render.write_mp4(video_path, frames, fps=1 / trainer.env.dt)
    print_fn(f"video of episode 0 ({length} steps, return {returns[0]:.1f}): {video_path}")
  return result


def extract(directory: str, member: int | str, out_dir: str, print_fn=print,
            env: Any = None) -> str:
  """Writes member `member` (an index, or "best") of the sweep checkpointed in `directory` as a
  single run's checkpoint in `out_dir`/checkpoints, with its config.json: its seed and swept
  values as plain settings, its latest state and its best agent. Returns that directory."""
  cfg, state, _, saved, best = _restore(directory, print_fn, env, with_best=True)
  indices = list(saved.get("member_indices", range(len(cfg.members()))))
  record = saved.get("record", {})
  if member == "best":
    member = indices[best_position(directory, record)]
  try:
    target, chosen = _write_member(cfg, state, best, record, indices, member, out_dir)
  except ValueError as error:
    raise ValueError(f"{directory}: {error}") from None
  print_fn(f"member {member} ({', '.join(f'{k}={v}' for k, v in chosen.items())}) of "
           f"{directory} is now the single run in {target}: its latest state, to train on"
           + (", and its best evaluation's agent, which eval loads" if best is not None else ""))
  return target


def best_position(directory: str, record: dict) -> int:
  """The position of the member with the best saved evaluation in a checkpoint's `record`."""
  scores = [-np.inf if v is None else v for v in record.get("best_return", [None])]
  if not np.isfinite(scores).any():
    raise ValueError(f"{directory}: no evaluation was saved yet, so no member is the best; "
                     "give a member's index")
  return int(np.argmax(scores))


def _position(directory: str, saved: dict, member: int | str) -> int:
  """`member` (a position, or "best") as a position; no older step has a best where the newest
  has none."""
  try:
    return best_position(directory, saved.get("record", {})) if member == "best" else member
  except ValueError as error:
    raise checkpoint.ConfigMismatch(str(error)) from None


def _restore(directory: str, print_fn, env: Any, with_best: bool = False):
  """`restore`'s three, then the saved config item and, `with_best`, the best agents."""
  mngr = open_checkpoints(directory)

  def load(step):
    cfg, members, saved = _saved_run(mngr, step, env)
    trainer = build(cfg, len(members))
    state = checkpoint.restore(mngr, step, init(cfg, trainer, members))
    best = checkpoint.restore_best(mngr, step, state.agent) if with_best else None
    return cfg, state, trainer, saved, best

  step, out = checkpoint.load_newest(mngr, load, print_fn)
  print_fn(f"restored {directory}, step {step}")
  return out


def open_checkpoints(directory: str):
  """The checkpoint manager of `directory`; a FileNotFoundError where it holds none."""
  if not os.path.isdir(directory):
    raise FileNotFoundError(f"no checkpoint directory {directory!r}")
  mngr = checkpoint.manager(directory)
  if not mngr.all_steps():
    raise FileNotFoundError(f"no checkpoint in {directory!r}")
  return mngr


def _saved_run(mngr, step, env: Any = None) -> tuple[RunConfig, list[dict], dict]:
  """The RunConfig saved at `step`, the members its checkpoint holds, and the saved item. A
  task that cannot be found, or is not `env`, is a ConfigMismatch: no older step does better."""
  saved = checkpoint.read_config(mngr, step)
  try:
    cfg = RunConfig.from_json(saved, env)
  except ValueError as error:
    raise checkpoint.ConfigMismatch(f"{mngr.directory}: {error}") from None
  everyone = cfg.members()
  return cfg, [everyone[i] for i in saved.get("member_indices", range(len(everyone)))], saved


def _write_member(cfg: RunConfig, state, best, record: dict, indices: list[int], member: int,
                  out_dir: str) -> tuple[str, dict]:
  """Writes member `member` of a sweep's restored state (holding members `indices`) as a single
  run's checkpoint. Returns (its directory, the member's seed and swept values)."""
  if member not in indices:
    raise ValueError(f"member {member} is not in the sweep: it holds members {indices}")
  position = indices.index(member)
  chosen = record.get("values", [cfg.members()[i] for i in indices])[position]
  agent_values = {k: v for k, v in chosen.items() if k not in ("seed", *TRAINER_DYNAMIC)}
  single = dataclasses.replace(
      cfg, seed=chosen["seed"], seeds=(), grid={}, pbt=None, out_dir=out_dir,
      agent_overrides={**cfg.agent_overrides, **agent_values},
      train=dataclasses.replace(cfg.train, **{k: chosen[k] for k in TRAINER_DYNAMIC
                                              if k in chosen}))
  one = jax.tree.map(lambda x: x[position:position + 1], jax.device_get((state, best)))
  target = os.path.join(out_dir, "checkpoints")
  mngr = checkpoint.manager(target)
  if mngr.all_steps():
    raise ValueError(f"{target} already holds a checkpoint; nothing was overwritten: choose "
                     "another out_dir")
  mine = {k: v[position:position + 1] for k, v in record.items()}
  config = {**single.to_json(), "member_indices": [0]}
  record = {**mine, "values": [{"seed": chosen["seed"]}], "parents": [0], "diverged": [False]}
  checkpoint.save(mngr, one[0], {**config, "record": record}, best=one[1])
  checkpoint.finish(mngr)
  with open(os.path.join(out_dir, "config.json"), "w") as f:
    json.dump(config, f, indent=1)
  return target, chosen
