"""What the Robolympics notebook shows, each in one call: a recorded evaluation of a trained
policy, inline videos (side by side, too), the NMA notebook's per-step reward plot, a run's learning
curve, and the tiny settings the tests run the notebook with.

    from mjx_hopper.faces import notebook
    from mjx_hopper.run import loop
from mjx_hopper.settings.training import TrainConfig
    result = loop.run(cfg)
    episodes = notebook.evaluate(result, num_episodes=5)  # its best evaluation's policy
    notebook.video(result.trainer.env, episodes, "policy.mp4")
    notebook.side_by_side({"random actions": "random.mp4", "trained": "policy.mp4"})
    notebook.plot_episode_rewards(episodes)
    notebook.plot_learning_curve(f"{cfg.out_dir}/log.csv")
"""

from __future__ import annotations

import csv
import dataclasses
import html

import jax
import numpy as np

from mjx_hopper import agents
from mjx_hopper.core import rollout
from mjx_hopper.envs import render
from mjx_hopper.run import loop
from mjx_hopper.settings.training import TrainConfig

TINY_TRAIN = TrainConfig(num_envs=4, unroll_length=2, batch_size=8, replay_ratio=2.0,
                               replay_size=64, min_replay=24, iterations_per_chunk=5)


def tiny(cfg: loop.RunConfig) -> loop.RunConfig:
  """`cfg` shrunk to seconds of training: the agent's tiny settings, 4 envs, 80 env steps of
  30-step episodes, an evaluation of 2 episodes every 40 env steps. Tests share its programs
  through the compile cache."""
  return dataclasses.replace(cfg, agent_overrides=agents.spec(cfg.agent).tiny, train=TINY_TRAIN,
                             episode_steps=30, total_env_steps=80, max_minutes=None,
                             eval_every=40, eval_episodes=2)


def evaluate(result: loop.Result, num_episodes: int, seed: int = 0, which: str = "best",
             member: int = 0, print_fn=print) -> dict[str, np.ndarray]:
  """Runs `num_episodes` episodes of the deterministic policy of a run's `result` (of a sweep's,
  its `member`): the policy of its best evaluation (which="latest": the latest), saying which,
  in one compiled call, recording what the notebook shows. Returns host arrays: "return" and
  "length" (num_episodes,), the mean of each reward term, "rewards" (num_episodes,
  episode_steps: each step's reward, 0 after the episode's end) and "qpos" (episode 0's poses,
  (episode_steps + 1, nq))."""
  env, agent = result.trainer.env, result.trainer.agent
  # On the host: a member's agent lies where its run placed it (a population's, on one of the
  # devices), and the program would be compiled again for each placement.
  agent_state = jax.device_get(result.policy(which, member))
  if which == "best" and result.best is not None:
    print_fn(f"the policy of the best evaluation (return {result.best_return[member]:,.1f})")
  else:
    print_fn(f"the latest policy{'' if which == 'latest' else ' (no evaluation yet)'}")

  # Traced as in a fresh process (docs/upstream.md: a program's compile-cache key depends on
  # what the process traced before), so that the same evaluation in another cell, kernel or
  # test loads from the compile cache what one of them compiled. JAX's compiled programs are
  # dropped from memory; a later run loads its own again from that cache.
  jax.clear_caches()

  @jax.jit
  def run(agent_state, key):
    return rollout.episodes(env, lambda obs, _: agent.policy(agent_state, obs), key,
                            num_episodes, record_qpos=True, record_rewards=True)

  return jax.device_get(run(agent_state, jax.random.PRNGKey(seed)))


def video(env, episodes: dict, path: str, width: int = 320, height: int = 240):
  """Episode 0 of `episodes` (from `evaluate`, or `rollout.episodes` with record_qpos) as an
  mp4 at `path`, returned as an inline video for the notebook."""
  from IPython.display import Video
  qpos = np.asarray(episodes["qpos"])[: int(episodes["length"][0]) + 1]
  render.write_mp4(path, env.render(qpos, width=width, height=height), fps=1 / env.dt)
  return Video(path, embed=True, html_attributes="controls loop autoplay muted")


def side_by_side(videos: dict[str, str], width: int = 320):
  """The mp4 files `videos` ({title: path}) in one row, each under its title, looping, as an
  inline HTML block for the notebook."""
  import base64

  from IPython.display import HTML
  figures = []
  for title, path in videos.items():
    with open(path, "rb") as f:
      data = base64.b64encode(f.read()).decode()
    figures.append(
        f'<figure style="display:inline-block;margin:0 8px 0 0"><video width="{width}" controls '
        f'loop autoplay muted src="data:video/mp4;base64,{data}"></video>'
        f"<figcaption>{html.escape(title)}</figcaption></figure>")
  return HTML("".join(figures))


def plot_episode_rewards(episodes: dict, ax=None):
  """The reward of every step, the episodes one after another, a colour each (the NMA notebook's
  plot). Returns the matplotlib Axes."""
  ax = ax or _axes()
  start = 0
  for i, (length, rewards) in enumerate(zip(episodes["length"], episodes["rewards"])):
    length = int(length)
    ax.plot(np.arange(start, start + length), rewards[:length], label=f"episode {i}")
    start += length
  ax.set(xlabel="step (episodes one after another)", ylabel="reward")
  ax.grid(True)
  ax.legend(fontsize="small")
  return ax


def read_log(path: str) -> dict[str, dict[str, np.ndarray]]:
  """A run's log.csv by kind of row ("train", "eval"): each column as a float array, NaN where
  a row left it empty."""
  with open(path, newline="") as f:
    rows = list(csv.DictReader(f))
  out = {}
  for kind in sorted({row["kind"] for row in rows}):
    mine = [row for row in rows if row["kind"] == kind]
    out[kind] = {name: np.array([_number(row.get(name)) for row in mine])
                 for name in mine[0] if name != "kind"}
  return out


def plot_learning_curve(path: str, ax=None):
  """A run's learning curve from its log.csv: the evaluation return (mean, and its spread over
  the episodes) and the return of the training episodes, against env steps. Returns the
  matplotlib Axes."""
  log = read_log(path)
  ax = ax or _axes()
  if "train" in log:
    ax.plot(log["train"]["env_steps"], log["train"]["episode_return"], alpha=0.4,
            label="training episodes (exploring)")
  if "eval" in log:
    steps, mean, std = (log["eval"][k] for k in ("env_steps", "eval_return", "eval_return_std"))
    line, = ax.plot(steps, mean, "o-", label="evaluation (deterministic policy)")
    ax.fill_between(steps, mean - std, mean + std, color=line.get_color(), alpha=0.2)
  ax.set(xlabel="env steps", ylabel="episode return")
  ax.grid(True)
  ax.legend(fontsize="small")
  return ax


def _axes():
  import matplotlib.pyplot as plt
  return plt.figure(figsize=(8, 3)).gca()


def _number(text) -> float:
  try:
    return float(text)
  except (TypeError, ValueError):
    return float("nan")


class LiveCurve:
  """A `progress_fn` for `loop.run` that draws the learning curve while training: one figure,
  redrawn in place at most every `every` seconds and at each evaluation.

      loop.run(cfg, progress_fn=notebook.LiveCurve())
  """

  def __init__(self, every: float = 5.0):
    self.every, self.last = every, -float("inf")
    self.train: list[tuple[int, float]] = []
    self.eval: list[tuple[int, float]] = []
    self.handle = None

  def __call__(self, env_steps: int, metrics: dict) -> None:
    import time
    if metrics["kind"] == "eval":
      self.eval.append((env_steps, float(np.mean(metrics["eval_return"]))))
    elif np.isfinite(np.mean(metrics["episode_return"])):
      self.train.append((env_steps, float(np.nanmean(metrics["episode_return"]))))
    if metrics["kind"] == "eval" or time.monotonic() - self.last >= self.every:
      self.last = time.monotonic()
      self.draw()

  def draw(self):
    """Draws the curve so far into the notebook's output, replacing the last drawing."""
    import io

    from IPython.display import Image, display
    from matplotlib.figure import Figure
    fig = Figure(figsize=(8, 3))
    ax = fig.subplots()
    for points, style, label in ((self.train, "-", "training episodes (exploring)"),
                                 (self.eval, "o-", "evaluation (deterministic policy)")):
      if points:
        ax.plot(*zip(*points), style, label=label)
    ax.set(xlabel="env steps", ylabel="episode return")
    ax.grid(True)
    if self.train or self.eval:
      ax.legend(fontsize="small", loc="upper left")
    png = io.BytesIO()
    fig.savefig(png, format="png", dpi=80, bbox_inches="tight")
    image = Image(png.getvalue())
    if self.handle is None:
      self.handle = display(image, display_id=True)
    else:
      self.handle.update(image)
    return fig
