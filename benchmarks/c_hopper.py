"""The Hopper with its physics in MuJoCo C, for c_physics.py and for training through the CLI
(`mjx-hopper train --env c_hopper:CHopper`, run from benchmarks/): its physics substeps, and its
resets' kinematics, run by `mujoco.batch` on threads, called from the compiled program through
`jax.pure_callback`; the observation, reward and termination stay the env's, in JAX."""

from __future__ import annotations

import functools
import threading
from unittest import mock

import jax
import mujoco
import mujoco.batch
import numpy as np
from mjx_hopper.envs import base

from mjx_hopper import envs

# What the C step reads of an env's mjx.Data and writes back: the state it continues from
# (MuJoCo's mjSTATE_INTEGRATION but for inputs the env never sets), and the positions that
# LocomotionEnv.step reads, which mj_step leaves one substep behind the state, as mjx.step does.
STATE = ("time", "qpos", "qvel", "act", "qacc_warmstart")
POSES = ("xpos", "xipos", "xquat", "xanchor", "geom_xpos", "geom_xmat")
INPUTS = STATE + ("ctrl",)


class CHopper(envs.Hopper):
  """The Hopper stepped by MuJoCo C on `threads` threads per call: a call per device's share of
  the batch, so 2 XLA devices with 1 thread each keep 2 cores busy."""

  def __init__(self, episode_steps: int = 1000, threads: int = 1):
    super().__init__(episode_steps)
    self.threads = threads
    self._shapes = {f: getattr(self._data0, f).shape for f in STATE + POSES}
    # Batches not in use, by size: a mujoco.batch.Batch serves one call at a time, and the
    # devices' calls come at once, each from any of XLA's threads (one Batch per thread, in a
    # threading.local, was freed with the thread's state and crashed the process).
    self._idle = {}
    self._lock = threading.Lock()

  def step(self, state, action):
    # `base._physics` is the step's only physics call: traced with the C path in its place.
    with mock.patch.object(base, "_physics", self._c_physics):
      return super().step(state, action)

  def _c_physics(self, model, data, substeps):
    """`data` after `substeps` mj_steps; `model` (a swapped env.sys) is not followed."""
    return self._in_c(data, STATE + POSES, lambda batch: batch.step(nstep=substeps))

  def _kinematics(self, data):
    """A reset's poses, from MuJoCo C's position stage."""
    return self._in_c(data, POSES, lambda batch: batch.forward(stage=mujoco.mjtStage.mjSTAGE_POS))

  def _in_c(self, data, fields, run):
    """`data` with `fields` as MuJoCo C leaves them after `run(batch)` from its state."""
    out = {f: jax.ShapeDtypeStruct(getattr(data, f).shape, getattr(data, f).dtype)
           for f in fields}
    new = jax.pure_callback(functools.partial(self._host, run, fields), out,
                            *(getattr(data, f) for f in INPUTS), vmap_method="broadcast_all")
    return data.replace(**new)

  def _host(self, run, fields, *inputs):
    lead = np.shape(inputs[0])  # the batch's shape, from time's; () for one env
    n = int(np.prod(lead))
    with self._lock:
      idle = self._idle.setdefault(n, [])
      batch = idle.pop() if idle else None
    if batch is None:
      batch = mujoco.batch.Batch(self.mj_model, n, nthread=self.threads)
      for f in POSES:  # bound before a call, or it reads zeros until the next
        batch.bind(f)
    for name, x in zip(INPUTS, inputs):
      field = batch.bind(name)
      field[:] = np.reshape(x, field.shape)
    run(batch)
    out = {f: np.reshape(batch.bind(f), lead + self._shapes[f]).astype(np.float32)
           for f in fields}
    with self._lock:
      self._idle[n].append(batch)
    return out
