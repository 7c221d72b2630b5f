"""Which way dpg's update runs its networks: XLA's (the flax modules) or fused GPU kernels
(pallas_mlp.py), chosen by `path`; and the fused kernels behind the flax modules' interface.

The two ways give the same results to rounding, so the choice is no part of a config or a
checkpoint: a run resumes on either.
"""

from __future__ import annotations

import os

import jax.numpy as jnp

from mjx_hopper.agents import networks

PATHS = ("auto", "fused", "xla")
ENV_VAR = "MJX_HOPPER_LEARNER"

# What "auto" picks. The fused kernels were measured no faster than XLA's update on the GPU
# presets (benchmarks/learner_throughput.py --learners xla,fused): XLA's, on every platform.
_AUTO = "xla"


def path(learner: str | None = None) -> str:
  """"fused" or "xla": `learner`, else $MJX_HOPPER_LEARNER, else "auto" (XLA's update)."""
  learner = learner or os.environ.get(ENV_VAR) or "auto"
  if learner not in PATHS:
    raise ValueError(f"learner path must be one of {list(PATHS)}, got {learner!r} "
                     f"(argument or ${ENV_VAR})")
  return _AUTO if learner == "auto" else learner


def _mlp_params(mlp: dict, head: dict | None = None):
  """A flax LayerNormMLP's (and an optional Dense head's) parameters as (kernels, biases,
  LayerNorm scale, LayerNorm bias)."""
  dense = [mlp[f"Dense_{i}"] for i in range(sum(k.startswith("Dense_") for k in mlp))]
  if head is not None:
    dense.append(head)
  return (tuple(d["kernel"] for d in dense), tuple(d["bias"] for d in dense),
          mlp["LayerNorm_0"]["scale"], mlp["LayerNorm_0"]["bias"])


def policy(net: networks.TanhPolicy, tiles=None, interpret: bool | None = None):
  """(params, obs) -> the policy's pre-tanh action (..., A), as `net.apply(..., squash=False)`.
  `tiles` and `interpret` are pallas_mlp.mlp's."""
  from mjx_hopper.agents.pallas_mlp import mlp  # Pallas loads only for the fused path
  dtype = jnp.dtype(net.dtype).name

  def apply(params, obs):
    return mlp(_mlp_params(params["params"]["LayerNormMLP_0"]), obs, dtype, tiles, interpret)
  return apply


def critic(net: networks.Critic, tiles=None, interpret: bool | None = None):
  """(params, obs, action) -> the critic's outputs, as `net.apply`."""
  from mjx_hopper.agents.pallas_mlp import mlp
  dtype = jnp.dtype(net.dtype).name

  def apply(params, obs, action):
    p = params["params"]
    x = jnp.concatenate([obs, jnp.clip(action, -1.0, 1.0)], axis=-1)
    if net.num_atoms == 1:
      return mlp(_mlp_params(p["LayerNormMLP_0"]), x, dtype, tiles, interpret)[..., 0]
    return mlp(_mlp_params(p["LayerNormMLP_0"], p["Dense_0"]), x, dtype, tiles, interpret)
  return apply
