"""Spreading a batch of envs over the local devices (several CPU devices, or GPUs).

The batch's leading axis is split evenly over the devices, and each device steps its own share
with `per_device`: the physics then runs with no traffic between devices. (Leaving the split to
XLA's automatic partitioner instead puts collectives inside MJX's solver loops, which hung on two
CPU devices for a batch of 128 Humanoids.)

On jax 0.11.2 (the newest jax for Python 3.12, so Colab's), XLA segfaults compiling any of our
programs that run shard_map over 2 devices, be they XLA:CPU devices or GPUs: the env stepper,
the training chunk, and Brax's pmap over our envs (in Shardy's
ManualComputationUnusedInputsPattern; seen 2026-11-26). XLA's older GSPMD partitioner compiles
and runs them (printing, at each compile, a warning that GSPMD will be deprecated), and jax 0.9.2
compiles them with Shardy. So `avoid_shardy_crash` switches such a jax to GSPMD in a process
that has several devices, unless the user chose a partitioner with JAX_USE_SHARDY_PARTITIONER;
every env (envs/base.py) and every mesh of mjx_hopper (`mesh`) calls it. `gspmd_in_this_thread`
does the same for one thread's compiles only.
"""

import contextlib
import logging
import os

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

BATCH = PartitionSpec("batch")
SHARDY_CRASHES = (0, 11)  # the first jax whose Shardy crashes on our programs over several devices


def _shardy_would_crash(num_devices: int) -> bool:
  """Whether this thread's partitioner is a Shardy that crashes on our programs over
  `num_devices`, and the user left the choice to us."""
  return (num_devices > 1 and jax.__version_info__ >= SHARDY_CRASHES
          and "JAX_USE_SHARDY_PARTITIONER" not in os.environ
          and jax.config.jax_use_shardy_partitioner)  # this thread's value


@contextlib.contextmanager
def gspmd_in_this_thread(num_devices: int):
  """A context in which this thread traces and compiles with GSPMD where Shardy would crash on
  programs over `num_devices`, and the rest of the process keeps its partitioner: the host's
  evaluation over several CPU devices compiles beside a training chunk on one GPU."""
  if not _shardy_would_crash(num_devices):
    yield
    return
  from jax._src import config  # jax_use_shardy_partitioner's thread-local form
  with config.use_shardy_partitioner(False):
    yield


def avoid_shardy_crash(num_devices: int) -> None:
  """With several devices, on a jax whose Shardy partitioner crashes on our programs, switches
  this process to the GSPMD partitioner and says so once (module docstring); otherwise, or where
  JAX_USE_SHARDY_PARTITIONER is set, changes nothing."""
  if _shardy_would_crash(num_devices):
    logging.getLogger(__name__).warning(
        "mjx_hopper: jax %s's Shardy partitioner crashes compiling programs over %d devices; "
        "this process now uses XLA's GSPMD partitioner (set JAX_USE_SHARDY_PARTITIONER to "
        "choose)", jax.__version__, num_devices)
    jax.config.update("jax_use_shardy_partitioner", False)


def mesh(devices, axis_names: tuple[str, ...]) -> Mesh:
  """`Mesh(devices, axis_names)`, after `avoid_shardy_crash`."""
  devices = np.asarray(devices)
  avoid_shardy_crash(devices.size)
  return Mesh(devices, axis_names)


def _mesh(batch_size: int, devices=None) -> Mesh | None:
  devices = jax.local_devices() if devices is None else devices
  if len(devices) == 1 or batch_size % len(devices):
    return None
  return mesh(devices, ("batch",))


def batch_sharding(batch_size: int) -> NamedSharding | None:
  """Shards axis 0 over every local device, or None when the batch does not divide evenly."""
  mesh = _mesh(batch_size)
  return None if mesh is None else NamedSharding(mesh, BATCH)


def shard(tree):
  """Places a pytree whose leaves share a leading batch axis across the local devices.

  Works inside jit too (as a sharding constraint), so compiled code keeps the batch split.
  """
  leaves = jax.tree.leaves(tree)
  sharding = batch_sharding(leaves[0].shape[0]) if leaves else None
  if sharding is None:
    return tree
  if isinstance(leaves[0], jax.core.Tracer):
    return jax.lax.with_sharding_constraint(tree, sharding)
  return jax.device_put(tree, sharding)


def per_device(fn, batch_size: int, devices=None):
  """Runs `fn` on each device's share of a batch of `batch_size`, over `devices` (default:
  every local one).

  Every argument and output of `fn` is a pytree whose leaves have the batch as leading axis;
  inside, `fn` sees 1/num_devices of it. With one device, or a batch that does not divide
  evenly, `fn` runs on the whole batch.
  """
  mesh = _mesh(batch_size, devices)
  if mesh is None:
    return fn

  def wrapped(*args):
    # check_vma off: MJX's solver mixes per-device and replicated values in its branches.
    return jax.shard_map(fn, mesh=mesh, in_specs=(BATCH,) * len(args), out_specs=BATCH,
                         check_vma=False)(*args)
  return wrapped
