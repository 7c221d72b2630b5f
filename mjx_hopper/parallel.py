"""Spreading a batch of envs over the local devices (several CPU devices, or GPUs)."""

import jax
from jax.sharding import Mesh, NamedSharding, PartitionSpec


def batch_sharding(batch_size: int) -> NamedSharding | None:
  """Shards axis 0 over every local device, or None when the batch does not divide evenly."""
  devices = jax.local_devices()
  if len(devices) == 1 or batch_size % len(devices):
    return None
  return NamedSharding(Mesh(devices, ("batch",)), PartitionSpec("batch"))


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
