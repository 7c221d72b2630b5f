"""Population-based training: every few evaluations, the worst members of a sweep take a copy of
a better member's agent and perturb the grid's settings (docs/pbt.md)."""

from __future__ import annotations

import jax
import numpy as np

from mjx_hopper.process import distributed
from mjx_hopper.settings.training import PBT


def exploit_explore(pbt: PBT, returns, diverged, values: dict, ranges: dict, quanta: dict,
                    rng):
  """One PBT step over a population: (sources, new values). `returns` (S,) are the members'
  evaluations, `diverged` (S,) their marks, `values` {setting: (S,) array} their settings now.
  sources[m] is the member whose agent m takes (m itself when kept); the new values are the
  sources' perturbed (times one of `pbt.factors`, then clipped to `ranges`), the kept members'
  unchanged. A setting with a quantum ({setting: q}: 1 for an integer setting) takes multiples
  of it, and a perturbation moves it by one quantum at least.

  The members rank by return, diverged ones (and those without a finite return) last, ties to
  the lower index. Sources are drawn from the best `count` = max(1, S * fraction) that are
  healthy; the worst `count` are replaced, and every diverged member too. With no healthy
  member, nothing changes."""
  score = np.where(np.asarray(diverged) | ~np.isfinite(returns), -np.inf, returns)
  order = np.argsort(-score, kind="stable")
  count = max(1, int(len(order) * pbt.fraction))
  pool = [m for m in order[:count] if np.isfinite(score[m])]
  lost = int(np.sum(~np.isfinite(score)))
  sources = np.arange(len(order))
  new = {name: np.array(v, copy=True) for name, v in values.items()}
  for member in order[len(order) - max(count, lost) if pool else len(order):]:
    if member in pool:
      continue
    source = int(pool[rng.integers(len(pool))])
    sources[member] = source
    for name, v in values.items():
      now = float(v[source])
      moved = now * pbt.factors[rng.integers(len(pbt.factors))]
      quantum = quanta.get(name)
      if quantum:
        steps = round(moved / quantum)
        moved = quantum * (steps if steps * quantum != now else steps + np.sign(moved - now))
      new[name][member] = np.clip(moved, *ranges[name])
  return sources, new



def make_step(pbt: PBT, grid: dict, trainer, seed: int, say):
  """PBT's step between chunks, for the members of `trainer`: step(state, returns, env_steps,
  members) -> state, where `members` is the run's `Members` record, which it updates."""
  config = trainer.config
  copy_members = jax.jit(_copy_members, out_shardings=trainer.shardings, donate_argnums=0,
                         static_argnames="data")

  def step(state, returns, env_steps: int, members):
    hparams, ratio = distributed.gather((state.agent.hparams, state.replay_ratio), "pbt")
    values = {name: np.asarray(ratio if name == "replay_ratio" else hparams[name])
              for name in grid}
    quanta = {name: 1 for name, v in values.items() if np.issubdtype(v.dtype, np.integer)}
    quanta["replay_ratio"] = config.batch_size / config.steps_per_iteration
    rng = np.random.default_rng([seed, env_steps, members.indices[0]])
    sources, new = exploit_explore(pbt, returns, members.diverged, values, pbt.ranges(grid),
                                   quanta, rng)
    moved = np.flatnonzero(sources != np.arange(len(sources)))
    ratio = new.pop("replay_ratio", ratio)
    # A diverged member's replay and envs hold non-finite steps: it takes its source's too.
    lost = moved[members.diverged[moved]]
    if len(lost):
      state = copy_members(state, lost, sources[lost], new, ratio, data=True)
    state = copy_members(state, moved, sources[moved], new, ratio, data=False)
    if "replay_ratio" in grid:
      new["replay_ratio"] = ratio
    members.copied(moved, sources, new)
    say(f"[pbt] {env_steps:,} env steps: " + "; ".join(
        f"member {members.indices[m]} copies member {members.parents[m]}, with "
        + " ".join(f"{k}={members.values[m][k]:g}" for k in grid) for m in moved))
    return state
  return step


def _copy_members(state, targets, sources, hparams: dict, replay_ratio, data: bool):
  """`state` with the agent of each member `targets` a copy of member `sources`' (and with
  `data`, its replay, envs and episode returns too), and the dynamic settings `hparams`
  ({name: (members,) values}) and `replay_ratio` in place of every member's."""
  def copy(tree):
    return jax.tree.map(lambda x: x.at[targets].set(x[sources]), tree)
  agent = copy(state.agent)
  agent = agent._replace(hparams={**agent.hparams, **hparams})
  state = state._replace(agent=agent, replay_ratio=replay_ratio)
  if data:
    state = state._replace(replay=copy(state.replay), env=copy(state.env),
                           episode_return=copy(state.episode_return))
  return state
