"""Orbax's layout of a checkpoint step, and its format version.

A step holds up to four items: "agent" (the agent's pytree: params, targets, optimizer
states), "trainer" (replay, env states, keys, counters), "best" (the agent's pytree at each
member's best evaluation so far, once there is one) and "config" (JSON: the RunConfig, env,
agent, package versions, the checkpoint's format version, and the run's `record` of its
members: their best evaluations, divergence and, under PBT, lineage). Keeping the agent apart
lets `read_agent` load a policy without reading the replay.
"""

from __future__ import annotations

import importlib.metadata
import os
from typing import TYPE_CHECKING

import jax
import numpy as np

import mjx_hopper
from mjx_hopper.core import train
from mjx_hopper.process import parallel
from mjx_hopper.store.failures import check_space, failed
from mjx_hopper.store.manifests import wait_and_record

if TYPE_CHECKING:
  import orbax.checkpoint as ocp

# The layout of the saved items. Every change to it raises FORMAT (CHANGELOG.md says so), and
# OLDEST_FORMAT is the oldest layout this version still reads. Checkpoints saved before formats
# were recorded count as format 1. Format 2: the env states hold their episode starts.
FORMAT = 2
OLDEST_FORMAT = 2
# The newest mjx_hopper that reads each format older than OLDEST_FORMAT.
READ_BY = {1: "0.2.0"}


class ConfigMismatch(ValueError):
  """A checkpoint saved by another config."""


class FormatMismatch(ConfigMismatch):
  """A checkpoint whose layout this version cannot read (an older or a newer format)."""


PACKAGES = ("mjx_hopper", "jax", "jaxlib", "mujoco", "mujoco-mjx", "flax", "optax",
            "orbax-checkpoint", "brax")


def versions() -> dict[str, str]:
  """The versions of mjx_hopper (its own, not an editable install's metadata) and of the
  packages it runs on."""
  out = {"mjx_hopper": mjx_hopper.__version__}
  for name in PACKAGES[1:]:
    try:
      out[name] = importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
      out[name] = "not installed"
  return out


def manager(directory: str, max_to_keep: int = 3) -> ocp.CheckpointManager:
  """A CheckpointManager over `directory` (created if missing), saving asynchronously."""
  # Imported here, not with the package: a run's first lines do not wait for orbax.
  import orbax.checkpoint as ocp
  options = ocp.CheckpointManagerOptions(max_to_keep=max_to_keep,
                                         enable_async_checkpointing=True)
  return ocp.CheckpointManager(os.path.abspath(directory), options=options,
                               item_names=("agent", "trainer", "best", "config"))


def _split(state: train.TrainState) -> tuple:
  trainer = {k: v for k, v in state._asdict().items() if k != "agent"}
  return state.agent, trainer


def _nonempty(tree) -> dict:
  """The leaves of `tree` by index, leaving out zero-size ones (orbax cannot write them; MJX's
  Data has some, such as `act` for models without actuator states)."""
  return {str(i): x for i, x in enumerate(jax.tree.leaves(tree)) if x.size}


def _rebuild(like, saved: dict):
  """`like`'s structure with the saved leaves, placed as `like`'s, and its zero-size leaves
  as empty arrays."""
  leaves, treedef = jax.tree.flatten(like)
  return treedef.unflatten([jax.device_put(saved[str(i)] if str(i) in saved
                                           else np.zeros(x.shape, x.dtype), x.sharding)
                            for i, x in enumerate(leaves)])


def save(mngr: ocp.CheckpointManager, state: train.TrainState, config: dict,
         best=None) -> int:
  """Starts saving `state` (and `best`, the agent's pytree at its best evaluations, when given)
  as step = its iteration count, after finishing the previous save (`wait_and_record`); returns
  the step. Call `wait_and_record(mngr)` before relying on it. A SaveFailed where the previous
  save failed, or where this one cannot fit on the disk (checked before anything is written) or
  start."""
  import orbax.checkpoint as ocp
  wait_and_record(mngr)
  step = train.iterations(state)
  check_space(mngr, step, (state, best))
  agent, trainer = _split(state)
  items = dict(agent=ocp.args.StandardSave(_nonempty(agent)),
               trainer=ocp.args.StandardSave(_nonempty(trainer)),
               config=ocp.args.JsonSave({**config, "versions": versions(),
                                         "checkpoint_format": FORMAT}))
  if best is not None:
    items["best"] = ocp.args.StandardSave(_nonempty(best))
  try:
    mngr.save(step, args=ocp.args.Composite(**items))
  except Exception as error:  # noqa: BLE001 - as in `wait_and_record`
    raise failed(mngr, step, error) from None
  return step


def _abstract(tree):
  """Shapes, dtypes and placements to restore into (replicated where none is set)."""
  replicated = jax.sharding.NamedSharding(parallel.mesh(jax.devices(), ("d",)),
                                          jax.sharding.PartitionSpec())

  def one(x):
    sharding = getattr(x, "sharding", None) or replicated
    return jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=sharding)
  return jax.tree.map(one, tree)


def read_state(mngr: ocp.CheckpointManager, step: int, like: train.TrainState) -> train.TrainState:
  """The TrainState saved at `step`, placed like `like` (a state or its abstract shapes)."""
  import orbax.checkpoint as ocp
  agent, trainer = _abstract(_split(like))
  out = mngr.restore(step, args=ocp.args.Composite(
      agent=ocp.args.StandardRestore(_nonempty(agent)),
      trainer=ocp.args.StandardRestore(_nonempty(trainer))))
  return train.TrainState(agent=_rebuild(agent, out.agent), **_rebuild(trainer, out.trainer))


def read_config(mngr: ocp.CheckpointManager, step: int) -> dict:
  """The config item saved at `step`; a FormatMismatch when this version cannot read its
  layout."""
  import orbax.checkpoint as ocp
  saved = mngr.restore(step, args=ocp.args.Composite(config=ocp.args.JsonRestore())).config
  check_format(saved, mngr.directory)
  return saved


def check_format(saved: dict, directory: str) -> None:
  """Raises a FormatMismatch naming both format versions when the checkpoint format recorded in
  `saved` (a config item; 1 where none is) is not one this version reads."""
  found = saved.get("checkpoint_format", 1)
  if OLDEST_FORMAT <= found <= FORMAT:
    return
  by = saved.get("versions", {}).get("mjx_hopper", "another version")
  reads = (f"format {FORMAT}" if OLDEST_FORMAT == FORMAT
           else f"formats {OLDEST_FORMAT} to {FORMAT}")
  todo = (f"use mjx_hopper {by} or newer" if found > FORMAT else
          f"use mjx_hopper {READ_BY.get(found, by)} to resume or evaluate it, or to export its "
          "policy")
  raise FormatMismatch(f"the checkpoint in {directory} has format {found} (saved by mjx_hopper "
                       f"{by}), and mjx_hopper {mjx_hopper.__version__} reads {reads}: {todo}; "
                       "nothing was written")


def has_best(mngr: ocp.CheckpointManager, step: int) -> bool:
  """Whether `step` holds the agent at its best evaluations (steps saved before any
  evaluation, or by older versions, do not)."""
  return os.path.isdir(os.path.join(mngr.directory, str(step), "best"))


def read_agent(mngr: ocp.CheckpointManager, step: int, like_agent, item: str = "agent"):
  """Only the agent's pytree saved at `step` (no replay is read): the latest ("agent") or the
  one of the best evaluations ("best")."""
  import orbax.checkpoint as ocp
  like_agent = _abstract(like_agent)
  saved = mngr.restore(step, args=ocp.args.Composite(
      **{item: ocp.args.StandardRestore(_nonempty(like_agent))}))[item]
  return _rebuild(like_agent, saved)


def read_best(mngr: ocp.CheckpointManager, step: int, like_agent):
  """The agent at the best evaluations saved at `step`, or None where the step holds none."""
  return read_agent(mngr, step, like_agent, "best") if has_best(mngr, step) else None
