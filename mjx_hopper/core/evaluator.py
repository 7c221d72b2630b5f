"""The run's evaluations: the compiled evaluation, the queue of those due, evaluation on the host's
CPU beside training on an accelerator, and each member's best agent."""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec as P

from mjx_hopper.core import rollout, train
from mjx_hopper.process import distributed
from mjx_hopper.settings.plan import Plan

MAX_PENDING = 3  # evaluations running on the host beyond which training waits for the oldest


class Pending(NamedTuple):
  """An evaluation due and not yet taken."""
  env_steps: int
  agent: Any             # the members' agents then (a copy: a chunk consumes the state's)
  diverged: np.ndarray   # the members diverged then, whose evaluation cannot be their best
  started: Any = None    # the result's arrays, once started (JAX computes them asynchronously)


class Done(NamedTuple):
  """A finished evaluation: its per-episode results per member ("return" and "length", each
  (members, episodes)), the agents it evaluated and the members diverged then."""
  env_steps: int
  result: dict
  agent: Any
  diverged: np.ndarray

  @property
  def returns(self) -> np.ndarray:
    """(members,): each member's mean return."""
    return self.result["return"].mean(-1)


def host_sharding(plan: Plan) -> NamedSharding | None:
  """Where `plan`'s evaluations run: None on the training's devices, or on the host's CPU
  devices (`Plan.on_host`), as many as its episodes spread evenly over."""
  if not plan.on_host:
    return None
  episodes, cpus = plan.cfg.eval_episodes, jax.devices("cpu")
  count = max(k for k in range(1, len(cpus) + 1) if episodes % k == 0)
  return NamedSharding(Mesh(np.array(cpus[:count]), ("host",)), P())


def lower(trainer: train.Trainer, plan: Plan, agent_shapes):
  """The evaluation of `plan`'s members' agents of `agent_shapes`, lowered where it runs
  (`host_sharding`)."""
  members, host = len(plan.members), host_sharding(plan)
  keys = jax.ShapeDtypeStruct((members, 2), jnp.uint32)
  if host is None:
    return trainer.evaluate.lower(agent_shapes, keys)
  evaluate = rollout.make_evaluate(trainer.env, trainer.agent, plan.cfg.eval_episodes, members,
                                   list(host.mesh.devices.flat))
  agent, keys = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=host),
                             (agent_shapes, keys))
  return evaluate.lower(agent, keys)


class Evaluator:
  """Evaluates every member of `plan` by its deterministic policy when asked, by `program` (the
  compiled `lower`'s future; None for a run with nothing left to train), on the training's
  devices or on the host's CPU devices beside training (`host_sharding`). `best` is each
  member's agent at its best evaluation (a resumed run's; None before any)."""

  def __init__(self, trainer: train.Trainer, plan: Plan, program, best=None):
    self.seeds, self.host = [m["seed"] for m in plan.members], host_sharding(plan)
    self.program, self.best = program, best
    self.latest: Done | None = None  # the latest evaluation kept
    self.pending: list[Pending] = []
    # Every member's agents copied, and chosen member by member: the host loop's chunk uses
    # them too, to freeze a sweep's diverged members.
    self.copy_agents = jax.jit(lambda tree: jax.tree.map(jnp.copy, tree),
                               out_shardings=trainer.shardings.agent)
    self.select_agents = jax.jit(select_members, out_shardings=trainer.shardings.agent)

  def submit(self, env_steps: int, agent, diverged: np.ndarray) -> None:
    """Queues an evaluation of `agent` (every member's) at `env_steps`."""
    self.pending.append(Pending(env_steps, self.copy_agents(agent), diverged.copy()))

  def compiling(self) -> bool:
    """Whether the evaluation's program is still compiling. It rests on this process's clock:
    over processes, `take` is given the value agreed on, before the evaluation's collectives."""
    return self.program is not None and not self.program.done()

  def take(self, wait: bool, compiling: bool) -> list[Done]:
    """The queued evaluations that are done, oldest first; with `wait`, all of them. On the
    training's devices every evaluation waits; on the host, only those beyond MAX_PENDING do.
    Those queued while the program compiled (`compiling`, agreed over processes) start here,
    once it is compiled (or with `wait`)."""
    if not self.pending or (compiling and not wait):
      return []
    self.pending = [p if p.started is not None else p._replace(started=self._start(p))
                    for p in self.pending]
    wait = wait or self.host is None
    out = []
    while self.pending and (wait or len(self.pending) > MAX_PENDING
                            or _finished(self.pending[0].started)):
      done = self.pending.pop(0)
      out.append(Done(done.env_steps, distributed.gather(done.started, "evaluation"), done.agent,
                      done.diverged))
    return out

  def keep(self, done: Done, better: np.ndarray) -> None:
    """Keeps what a taken evaluation leaves: its results as the latest, and its agents of the
    members that beat their best (`better`, from the members' record)."""
    self.latest = done
    if self.best is None:
      self.best = done.agent  # members with no best yet hold this one meanwhile
    elif better.any():
      self.best = self.select_agents(better, done.agent, self.best)

  def _start(self, pending: Pending):
    # On the host: over processes, the program takes NumPy as every process's same value.
    keys = jax.device_get(_evaluation_keys(train.seed_bits(self.seeds),
                                           train.seed_bits(pending.env_steps)))
    agent = pending.agent
    if self.host is not None:
      agent, keys = jax.device_put((agent, keys), self.host)
    return self.program.result()(agent, keys)


@jax.jit
@functools.partial(jax.vmap, in_axes=(0, None))
def _evaluation_keys(seed, env_steps):
  """(members, 2): the key of each member's evaluation at `env_steps`, in one program."""
  return jax.random.fold_in(jax.random.PRNGKey(seed), env_steps)


def _finished(started) -> bool:
  """Whether a started evaluation's arrays are computed."""
  return all(x.is_ready() for x in jax.tree.leaves(started))


def select_members(mask, a, b):
  """Member m of pytree `a` where mask[m], else of `b`."""
  return jax.tree.map(
      lambda x, y: jnp.where(mask.reshape((-1,) + (1,) * (x.ndim - 1)), x, y), a, b)
