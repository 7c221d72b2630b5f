"""The host loop: compiled chunks, with logging, progress and evaluation in between.

    from mjx_hopper import loop
    result = loop.run(loop.RunConfig(env="Hopper", agent="d4pg", total_env_steps=200_000))
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import time
from typing import Any, Callable

import jax
import numpy as np
from tqdm.auto import tqdm

from mjx_hopper import agents, checkpoint, envs, train
from mjx_hopper.logger import LEARNER_FIELDS, RETURNS, Logger


@dataclasses.dataclass(frozen=True)
class RunConfig:
  """A whole training run: what to train, how, for how long, and where its files go."""

  env: str = "Hopper"
  agent: str = "d4pg"
  preset: str = "cpu"
  agent_overrides: dict = dataclasses.field(default_factory=dict)
  train: train.TrainConfig = train.TrainConfig()
  total_env_steps: int = 1_000_000
  max_minutes: float | None = None  # also stop (and save) after this much wall-clock time
  episode_steps: int = 1000
  eval_every: int = 200_000      # env steps between evaluations
  eval_episodes: int = 16
  seed: int = 0
  out_dir: str = "runs/train"     # log.csv, config.json and (by default) checkpoints/
  tensorboard_dir: str | None = None  # also log.csv's scalars as TensorBoard events here
  time_delta: float = 10.0       # seconds between terminal log lines
  checkpoint_minutes: float = 10.0
  keep_checkpoints: int = 3

  def __post_init__(self):
    if self.env not in envs.list_envs():
      raise ValueError(f"unknown env {self.env!r}; valid envs are {envs.list_envs()}")
    agents.config(self.agent, self.preset, **self.agent_overrides)  # raises on bad names
    for name in ("total_env_steps", "eval_every", "eval_episodes"):
      if getattr(self, name) < 1:
        raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")

  def agent_config(self):
    return agents.config(self.agent, self.preset, **self.agent_overrides)

  def to_json(self) -> dict:
    out = dataclasses.asdict(self)
    out["agent_config"] = dataclasses.asdict(self.agent_config())
    return out

  @classmethod
  def from_json(cls, saved: dict) -> "RunConfig":
    fields = {f.name for f in dataclasses.fields(cls)}
    kwargs = {k: v for k, v in saved.items() if k in fields}
    kwargs["train"] = train.TrainConfig(**saved["train"])
    return cls(**kwargs)


@dataclasses.dataclass
class Result:
  state: train.TrainState
  trainer: train.Trainer
  history: list[dict]            # every logged row (train and eval)
  evaluation: dict[str, Any]     # the final evaluation's per-episode arrays


def build(cfg: RunConfig) -> train.Trainer:
  env = envs.make(cfg.env, episode_steps=cfg.episode_steps)
  agent = agents.make(cfg.agent, env.observation_size, env.action_size, cfg.agent_config())
  return train.make_trainer(env, agent, cfg.train, eval_episodes=cfg.eval_episodes)


def run(cfg: RunConfig, checkpoint_dir: str | None = None, progress: bool = True,
        print_fn=print) -> Result:
  """Trains until `total_env_steps`, evaluating every `eval_every` env steps and at the end.

  Writes `out_dir`/log.csv (every chunk's and every evaluation's metrics), config.json and,
  with `cfg.tensorboard_dir`, the same scalars as TensorBoard events. Prints a short line
  every `time_delta` seconds and each evaluation, above the progress bar. Checkpoints go to
  `checkpoint_dir` (default `out_dir`/checkpoints) every `checkpoint_minutes`, at the end,
  and on Ctrl-C or SIGTERM (after the chunk in flight); a run whose checkpoint_dir already
  holds one resumes from it.
  """
  t_start = time.perf_counter()
  say = _above_progress_bars(print_fn)
  os.makedirs(cfg.out_dir, exist_ok=True)
  checkpoint_dir = checkpoint_dir or os.path.join(cfg.out_dir, "checkpoints")
  trainer = build(cfg)
  mngr = checkpoint.manager(checkpoint_dir, cfg.keep_checkpoints)
  key = jax.random.PRNGKey(cfg.seed)
  state = checkpoint.resume(mngr, trainer.init(key), cfg.to_json(), say)
  with open(os.path.join(cfg.out_dir, "config.json"), "w") as f:  # once resuming is agreed
    json.dump(cfg.to_json(), f, indent=1)
  env_steps = int(state.iteration) * cfg.train.steps_per_iteration
  logger = Logger(os.path.join(cfg.out_dir, "log.csv"), cfg.time_delta, say,
                  LEARNER_FIELDS[cfg.agent], cfg.tensorboard_dir, start_step=env_steps)
  per_chunk = cfg.train.steps_per_iteration * cfg.train.iterations_per_chunk
  say(f"{cfg.env} with {cfg.agent} ({cfg.preset}): {cfg.train.num_envs} envs on "
      f"{len(jax.local_devices())} {jax.local_devices()[0].platform} device(s), "
      f"{per_chunk:,} env steps and "
      f"{cfg.train.updates_per_iteration * cfg.train.iterations_per_chunk:,} updates "
      "per chunk")
  bar = (_progress_bar(cfg.total_env_steps, env_steps)
         if progress and env_steps < cfg.total_env_steps else None)
  _status(bar, "compiling the training step")
  next_eval = (env_steps // cfg.eval_every + 1) * cfg.eval_every
  evaluation, last_save = None, time.monotonic()

  def evaluate():
    _status(bar, "evaluating")
    result = jax.device_get(trainer.evaluate(state.agent, jax.random.fold_in(key, env_steps)))
    logger.write({"kind": "eval", "env_steps": env_steps, "wall_s": time.perf_counter() - t_start,
                  "eval_return": float(np.mean(result["return"])),
                  "eval_return_std": float(np.std(result["return"])),
                  "eval_length": float(np.mean(result["length"]))}, force=True)
    return result

  with checkpoint.StopRequest() as stop, logger:
    deadline = t_start + 60 * cfg.max_minutes if cfg.max_minutes else float("inf")
    while (env_steps < cfg.total_env_steps and not stop.requested
           and time.perf_counter() < deadline):
      t0 = time.perf_counter()
      state, metrics = trainer.train_chunk(state)
      metrics = jax.device_get(metrics)
      env_steps = int(state.iteration) * cfg.train.steps_per_iteration
      row = {"kind": "train", "env_steps": env_steps, "updates": int(state.updates),
             "wall_s": time.perf_counter() - t_start,
             "steps_per_s": per_chunk / (time.perf_counter() - t0),
             **{k: float(v) for k, v in metrics.items()}}
      logger.write(row)
      if (env_steps >= next_eval or env_steps >= cfg.total_env_steps
          or time.perf_counter() >= deadline):
        evaluation = evaluate()
        next_eval += cfg.eval_every
      if time.monotonic() - last_save >= 60 * cfg.checkpoint_minutes:
        checkpoint.save(mngr, state, cfg.to_json())
        last_save = time.monotonic()
      if bar is not None:
        bar.update(min(env_steps, cfg.total_env_steps) - bar.n)
        _status(bar, logger.describe(RETURNS, sep=", "))
    if bar is not None:
      bar.close()
    checkpoint.save(mngr, state, cfg.to_json())
    checkpoint.finish(mngr)
  say(_summary(cfg, stop.requested, env_steps, time.perf_counter() - t_start, evaluation,
               logger.csv_path, checkpoint_dir))
  return Result(state, trainer, logger.rows, evaluation)


def _summary(cfg: RunConfig, stopped: bool, env_steps: int, seconds: float,
             evaluation: dict | None, csv_path: str, checkpoint_dir: str) -> str:
  """The run's last line: why it ended, how far it got, its final evaluation and its files."""
  parts = [f"{'stopped by a signal' if stopped else 'done'}: {env_steps:,} env steps in "
           f"{seconds:.0f} s"]
  if evaluation is not None:
    parts.append(f"evaluation return {np.mean(evaluation['return']):.1f} over "
                 f"{len(evaluation['return'])} episodes")
  parts.append(f"log: {csv_path}")
  if cfg.tensorboard_dir:
    parts.append(f"TensorBoard: {cfg.tensorboard_dir}")
  parts.append(f"checkpoint: {checkpoint_dir}")
  return "; ".join(parts)


def restore(directory: str, print_fn=print):
  """(RunConfig, TrainState, Trainer) of the newest readable checkpoint in `directory`: the
  whole run as saved, replay included, rebuilt from the config saved beside it. After a Colab
  restart this is the one call that gets a run back; `run(cfg, checkpoint_dir=directory)`
  continues it."""
  mngr = _existing_manager(directory)

  def load(step):
    cfg = RunConfig.from_json(checkpoint.read_config(mngr, step))
    trainer = build(cfg)
    fresh = trainer.init(jax.random.PRNGKey(cfg.seed))
    return cfg, checkpoint.restore(mngr, step, fresh), trainer

  step, out = checkpoint.load_newest(mngr, load, print_fn)
  print_fn(f"restored {directory}, step {step}")
  return out


def _existing_manager(directory: str):
  if not os.path.isdir(directory):
    raise FileNotFoundError(f"no checkpoint directory {directory!r}")
  mngr = checkpoint.manager(directory)
  if not mngr.all_steps():
    raise FileNotFoundError(f"no checkpoint in {directory!r}")
  return mngr


def load_policy(directory: str):
  """(RunConfig, agent state, Trainer) of the newest readable checkpoint in `directory`; reads
  only the agent's item, not the replay."""
  mngr = _existing_manager(directory)

  def load(step):
    cfg = RunConfig.from_json(checkpoint.read_config(mngr, step))
    trainer = build(cfg)
    like = jax.eval_shape(trainer.agent.init, jax.random.PRNGKey(0))
    return cfg, checkpoint.restore_agent(mngr, step, like), trainer

  return checkpoint.load_newest(mngr, load)[1]


def _progress_bar(total: int, initial: int):
  return tqdm(total=total, initial=min(initial, total), unit=" env steps", unit_scale=True,
              dynamic_ncols=True)


def _status(bar, text: str) -> None:
  """Shows `text` after the progress bar's counts (nothing without a bar)."""
  if bar is not None:
    bar.set_postfix_str(text)


def _above_progress_bars(print_fn: Callable[[str], None]) -> Callable[[str], None]:
  """`print_fn`, writing above any tqdm progress bar on the terminal rather than into its
  line: tqdm clears the bar, the line is printed (and stdout flushed), tqdm redraws it."""

  def say(line: str) -> None:
    with tqdm.external_write_mode():
      print_fn(line)
      sys.stdout.flush()
  return say
