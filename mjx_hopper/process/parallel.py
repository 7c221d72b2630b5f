"""Spreading a batch of envs over the local devices (several CPU devices, or GPUs).

The batch's leading axis is split evenly over the devices, and each device steps its own share
with `per_device`: the physics then runs with no traffic between devices. (Leaving the split to
XLA's automatic partitioner instead puts collectives inside MJX's solver loops, which hung on two
CPU devices for a batch of 128 Humanoids.)

On some JAX versions XLA's Shardy partitioner crashes compiling our programs over several devices:
`mjx_hopper.setup` then switches the process to the GSPMD partitioner.
"""

import os

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

BATCH = PartitionSpec("batch")


def cores() -> int:
  """The CPU cores this process may run on."""
  if hasattr(os, "sched_getaffinity"):  # Linux: the cores it is allowed, not the machine's
    return len(os.sched_getaffinity(0))
  return os.cpu_count() or 1


def mesh(devices, axis_names: tuple[str, ...]) -> Mesh:
  """`Mesh(devices, axis_names)`."""
  return Mesh(np.asarray(devices), axis_names)


def _mesh(batch_size: int, devices=None) -> Mesh | None:
  devices = jax.devices() if devices is None else devices
  if len(devices) == 1 or batch_size % len(devices):
    return None
  return mesh(devices, ("batch",))


def batch_sharding(batch_size: int) -> NamedSharding | None:
  """Shards axis 0 over every device (of every process), or None when the batch does not divide
  evenly."""
  mesh = _mesh(batch_size)
  return None if mesh is None else NamedSharding(mesh, BATCH)


def shard(tree):
  """Places a pytree whose leaves share a leading batch axis across the devices.

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
  every process's), or over a Mesh's devices with the batch split over all its axes (a
  trainer's: `fn` is then traced in the trainer's context, and shares its traces).

  Every argument and output of `fn` is a pytree whose leaves have the batch as leading axis;
  inside, `fn` sees 1/num_devices of it. With one device (and no Mesh), or a batch that does
  not divide evenly, `fn` runs on the whole batch.
  """
  if isinstance(devices, Mesh):
    mesh, spec = devices, PartitionSpec(devices.axis_names)
    if batch_size % mesh.size:
      return fn
  else:
    mesh, spec = _mesh(batch_size, devices), BATCH
    if mesh is None:
      return fn

  def wrapped(*args):
    # check_vma off: MJX's solver mixes per-device and replicated values in its branches.
    return jax.shard_map(fn, mesh=mesh, in_specs=(spec,) * len(args), out_specs=spec,
                         check_vma=False)(*args)
  return wrapped

