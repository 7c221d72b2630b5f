"""MuJoCo C as an env's physics on the CPU (`physics="c"`): the control step's substeps and a
reset's kinematics run in MuJoCo's C engine (`mujoco.batch`, a batch of simulations on threads),
called from the compiled program through `jax.pure_callback`; the observation, reward and
termination stay the env's, in JAX. It needs no XLA compile of MJX's physics, which is most of a
training program's compile on the CPU.

A state's mjx.Data then holds what MuJoCo C wrote back: the state (`STATE`) and the poses that
the observation and reward read (`POSES`); its other fields (contacts, forces, velocities of
bodies) stay as the reset made them. A task of one's own that reads those needs physics="mjx".
"""

from __future__ import annotations

import copy
import functools
import threading

import jax
import mujoco
import mujoco.batch
import numpy as np

from mjx_hopper.process import parallel

# What a C step reads of an env's mjx.Data and writes back: the state it continues from
# (MuJoCo's mjSTATE_INTEGRATION but for inputs the env never sets), and the poses that
# LocomotionEnv.step reads, which mj_step leaves one substep behind the state, as mjx.step does.
STATE = ("time", "qpos", "qvel", "act", "qacc_warmstart")
POSES = ("xpos", "xipos", "xquat", "xanchor", "geom_xpos", "geom_xmat")
INPUTS = STATE + ("ctrl",)


def threads_per_call() -> int:
  """MuJoCo C's threads for one call: a call steps one device's share of the batch, and the
  devices' calls come at once, so the cores this process may use are shared out among them."""
  return max(1, parallel.cores() // len(jax.local_devices()))


class CPhysics:
  """An env's physics in MuJoCo C: `step` and `kinematics` take and return an mjx.Data, one
  env's or a batch's (under vmap the callback takes the whole batch at once)."""

  def __init__(self, model: mujoco.MjModel, data0):
    if model.nhistory or model.nplugin:  # state that STATE does not carry between calls
      raise ValueError(f"physics='c' carries no delay history or plugin state between steps, and "
                       f"this model has {model.nhistory} history values and {model.nplugin} "
                       "plugins: use physics='mjx'")
    # A state that is not finite stays so, ending its episode as under MJX, rather than being
    # reset to the model's start by MuJoCo's warning handler.
    self.model = copy.deepcopy(model)
    self.model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_AUTORESET
    self._shapes = {f: getattr(data0, f).shape for f in STATE + POSES}
    self._dtypes = {f: getattr(data0, f).dtype for f in STATE + POSES}
    self.threads = threads_per_call()
    # Batches not in use, by size: a mujoco.batch.Batch serves one call at a time, and each
    # call may come from any of XLA's threads (one Batch per thread, in a threading.local, was
    # freed with the thread's state and crashed the process).
    self._idle: dict[int, list] = {}
    self._lock = threading.Lock()

  def step(self, data, substeps: int):
    """`data` after `substeps` of MuJoCo's mj_step."""
    return self._in_c(data, STATE + POSES, lambda batch: batch.step(nstep=substeps))

  def kinematics(self, data):
    """`data`'s poses for its qpos: MuJoCo's position stage."""
    return self._in_c(data, POSES,
                      lambda batch: batch.forward(stage=mujoco.mjtStage.mjSTAGE_POS))

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
      batch = mujoco.batch.Batch(self.model, n, nthread=self.threads)
      for f in POSES:  # bound before a call, or it reads zeros until the next
        batch.bind(f)
    for name, x in zip(INPUTS, inputs):
      field = batch.bind(name)
      field[:] = np.reshape(x, field.shape)
    run(batch)
    out = {f: np.reshape(batch.bind(f), lead + self._shapes[f]).astype(self._dtypes[f])
           for f in fields}
    with self._lock:
      self._idle[n].append(batch)
    return out
