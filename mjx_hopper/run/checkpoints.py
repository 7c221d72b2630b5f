"""A run read back from its checkpoints, for every caller (`eval`, `export`, the notebook, the
benchmarks; `loop.resume` goes on training one): `restore` (the whole state), `saved_config`,
`load_member` and `load_policy` (one member's agent), `evaluate_checkpoint` and `extract` (one
member of a sweep as a single run). Each reads the newest step that reads whole."""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import numpy as np

from mjx_hopper import store
from mjx_hopper.core import rollout, train
from mjx_hopper.run import trainers
from mjx_hopper.settings.config import TRAINER_DYNAMIC, RunConfig
from mjx_hopper.settings.plan import Plan, resolve
from mjx_hopper.store.run_folder import RunFolder, Saved, open_checkpoints


def check_which(which: str) -> None:
  """Raises ValueError unless `which` names the best evaluation's agent or the latest."""
  if which not in ("best", "latest"):
    raise ValueError(f"which must be 'best' or 'latest', got {which!r}")


def built_here(cfg: RunConfig, print_fn=print) -> RunConfig:
  """A checkpoint's `cfg` as this process builds it: on MJX, saying so, where it trained on
  MuJoCo C (which runs on the CPU alone) and JAX runs on an accelerator. The engine is not the
  task: a checkpoint reads, evaluates and trains on under either."""
  platform = _platform()
  if cfg.physics != "c" or platform == "cpu":
    return cfg
  print_fn(f"the checkpoint trained on MuJoCo C's physics, which runs on the CPU alone: it runs "
           f"on MJX's here ({platform})")
  return dataclasses.replace(cfg, physics="mjx")


def _platform() -> str:
  """The platform of this process's first device, where its envs are built."""
  return jax.local_devices()[0].platform


def restore(directory: str, print_fn=print, env: Any = None):
  """(RunConfig, TrainState, Trainer) of the newest readable checkpoint in `directory`, replay
  included: after a Colab restart, the one call that gets a run back. `env` is the run's task,
  for one that cannot be imported (defined in a notebook)."""
  return _restore(directory, print_fn, env)[:3]


def saved_config(directory: str, print_fn=print, env: Any = None) -> RunConfig:
  """The RunConfig of the newest readable checkpoint in `directory`; `env` as in `restore`."""
  mngr = open_checkpoints(directory)
  return store.load_newest(mngr, lambda step: Saved.read(mngr, step, env).config, print_fn)[1]


class Member(NamedTuple):
  """One member's policy read from a checkpoint (`load_member`)."""

  plan: Plan          # its run's settings, resolved for the members the step holds
  agent: Any          # its agent state, without the member axis
  trainer: train.Trainer
  saved: Saved        # the checkpoint step it was read from
  position: int       # its position along the step's member axis
  best: bool          # whether `agent` is its best evaluation's (else the latest)

  @property
  def config(self) -> RunConfig:
    """Its run's config, as this process resolved it (`plan.cfg`)."""
    return self.plan.cfg


def load_policy(directory: str, member: int | str | None = None, env: Any = None,
                which: str = "best", print_fn=print):
  """(RunConfig, agent state, Trainer) of member `member` of the newest readable checkpoint in
  `directory` (`load_member`)."""
  loaded = load_member(directory, member, env, which, print_fn)
  return loaded.config, loaded.agent, loaded.trainer


def load_member(directory: str, member: int | str | None = None, env: Any = None,
                which: str = "best", print_fn=print) -> Member:
  """The newest readable checkpoint's member `member` (its index, as log.csv names it; "best":
  the member of the best evaluation; None: a single run's only one), at its best evaluation
  (or which="latest"), read without the replay. Says which policy it loaded."""
  check_which(which)
  mngr = open_checkpoints(directory)

  def load(step):
    saved = Saved.read(mngr, step, env)
    position, members = saved.position(member), saved.member_settings()
    plan, trainer = _built(saved, print_fn)
    like = jax.eval_shape(lambda k: trainers.init(plan, trainer, members).agent, 0)
    agents_state, best = saved.agents(mngr, like, which)
    score = saved.record.get("best_return", [None] * len(members))[position] if best else None
    if score is not None:
      print_fn(f"the policy of its best evaluation: return {score:.1f} at "
               f"{saved.record['best_env_steps'][position]:,} env steps")
    elif best:
      print_fn("the policy of its first evaluation (none of its evaluations was finite)")
    else:
      print_fn(f"the latest policy, at {step * trainer.config.steps_per_iteration:,} env steps"
               + ("" if which == "latest" else " (no evaluation was saved yet)"))
    return Member(plan, jax.tree.map(lambda x: x[position], agents_state), trainer, saved,
                  position, best)

  return store.load_newest(mngr, load)[1]


def evaluate_checkpoint(directory: str, member: int | str | None = None, episodes: int = 16,
                        seed: int = 0, video_path: str | None = None, which: str = "best",
                        env: Any = None, print_fn=print) -> dict:
  """Evaluates a checkpoint's policy (as `load_member` picks it) over `episodes` episodes, and
  with `video_path`, films episode 0 as an mp4. Returns the per-episode "return" and "length"."""
  cfg, agent_state, trainer = load_policy(directory, member, env, which, print_fn)
  result = jax.device_get(jax.jit(lambda s, k: rollout.evaluate(
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
  position = saved.position(member)
  target, chosen = _write_member(saved, state, best, position, out_dir)
  print_fn(f"member {saved.indices[position]} "
           f"({', '.join(f'{k}={v}' for k, v in chosen.items())}) of {directory} is now the "
           f"single run in {target}: its latest state, to train on"
           + (", and its best evaluation's agent, which eval loads" if best is not None else ""))
  return target


def _restore(directory: str, print_fn, env: Any, with_best: bool = False):
  """`restore`'s three, then the step read (`Saved`) and, `with_best`, the best agents."""
  mngr = open_checkpoints(directory)

  def load(step):
    saved = Saved.read(mngr, step, env)
    plan, trainer = _built(saved, print_fn)
    state = store.read_state(mngr, step, trainers.init(plan, trainer, saved.member_settings()))
    best = store.read_best(mngr, step, state.agent) if with_best else None
    return plan.cfg, state, trainer, saved, best

  step, out = store.load_newest(mngr, load, print_fn)
  print_fn(f"restored {directory}, step {step}")
  return out


def _built(saved: Saved, print_fn) -> tuple[Plan, train.Trainer]:
  """A checkpoint step's plan and trainer as this process builds them (`built_here`), for the
  members the step holds."""
  plan = resolve(built_here(saved.config, print_fn), len(saved.indices))
  return plan, trainers.build(plan)


def _write_member(saved: Saved, state, best, position: int, out_dir: str) -> tuple[str, dict]:
  """Writes the member at `position` of a sweep's restored state as a single run's
  checkpoint. Returns (its directory, the member's seed and swept values)."""
  cfg, record = saved.config, saved.record
  chosen = record.get("values", saved.member_settings())[position]
  agent_values = {k: v for k, v in chosen.items() if k not in ("seed", *TRAINER_DYNAMIC)}
  single = dataclasses.replace(
      cfg, seed=chosen["seed"], seeds=(), grid={}, pbt=None, out_dir=out_dir,
      agent_overrides={**cfg.agent_overrides, **agent_values},
      train=dataclasses.replace(cfg.train, **{k: chosen[k] for k in TRAINER_DYNAMIC
                                              if k in chosen}))
  one = jax.tree.map(lambda x: x[position:position + 1], jax.device_get((state, best)))
  folder = RunFolder(out_dir)
  mngr = store.manager(folder.checkpoints)
  if mngr.all_steps():
    raise ValueError(f"{folder.checkpoints} already holds a checkpoint; nothing was "
                     "overwritten: choose another out_dir")
  mine = {k: v[position:position + 1] for k, v in record.items()}
  config = single.saved([0])
  record = {**mine, "values": [{"seed": chosen["seed"]}], "parents": [0], "diverged": [False]}
  store.save(mngr, one[0], {**config, "record": record}, best=one[1])
  store.wait_and_record(mngr)
  folder.write_config(config)
  return folder.checkpoints, chosen
