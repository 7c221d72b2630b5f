"""Spreading a batch of envs over the local devices (several CPU devices, or GPUs).

The batch's leading axis is split evenly over the devices, and each device steps its own share
with `per_device`: the physics then runs with no traffic between devices. (Leaving the split to
XLA's automatic partitioner instead puts collectives inside MJX's solver loops, which hung on two
CPU devices for a batch of 128 Humanoids.)

On some JAX versions XLA's Shardy partitioner crashes compiling our programs over several devices
(`SHARDY_CRASHES`); `avoid_shardy_crash` then switches the process to the GSPMD partitioner.
"""

import logging
import os

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

BATCH = PartitionSpec("batch")
SHARDY_CRASHES = (0, 11)  # the first jax whose Shardy crashes on our programs over several devices


def _shardy_would_crash(num_devices: int) -> bool:
  """Whether the partitioner is a Shardy that crashes on our programs over `num_devices`, and
  the user left the choice to us."""
  return (num_devices > 1 and jax.__version_info__ >= SHARDY_CRASHES
          and "JAX_USE_SHARDY_PARTITIONER" not in os.environ
          and jax.config.jax_use_shardy_partitioner)


def avoid_shardy_crash(num_devices: int) -> None:
  """Switches the process to GSPMD where Shardy would crash over `num_devices` (logged at info
  level); changes nothing where JAX_USE_SHARDY_PARTITIONER is set."""
  if _shardy_would_crash(num_devices):
    logging.getLogger(__name__).info(
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


# Where a launcher tells a process its place: (index variable, count variable).
LAUNCHERS = (("SLURM_PROCID", "SLURM_NTASKS"), ("OMPI_COMM_WORLD_RANK", "OMPI_COMM_WORLD_SIZE"),
             ("PMI_RANK", "PMI_SIZE"))


def join_processes(coordinator: str | None = None, num_processes: int | None = None,
                   process_id: int | None = None) -> tuple[int, int]:
  """(this process's index, the number of processes) of a sweep spread over processes: from the
  arguments, else from the launcher's environment (SLURM, Open MPI, MPICH). The members never
  exchange data, so each process trains its share alone; `coordinator` is not needed."""
  del coordinator  # accepted for the command lines that name one
  if num_processes is None or process_id is None:
    found = [(int(os.environ[i]), int(os.environ[n])) for i, n in LAUNCHERS
             if i in os.environ and n in os.environ]
    if not found:
      raise ValueError("a sweep over processes needs --num-processes and --process-id, or a "
                       f"launcher that sets one of {[i for i, _ in LAUNCHERS]}")
    process_id, num_processes = found[0]
  if not 0 <= process_id < num_processes:
    raise ValueError(f"process id {process_id} is not in 0 to {num_processes - 1}")
  return process_id, num_processes


def process_share(total: int, process: tuple[int, int] | None = None) -> list[int]:
  """The indices of the members this process trains, of `total`: all of them, or for `process`
  = (index, count), an even, contiguous share."""
  index, count = process or (0, 1)
  if total % count:
    raise ValueError(f"{total} members do not split evenly over {count} processes")
  share = total // count
  return list(range(index * share, (index + 1) * share))
