"""The NMA notebook's networks (acme's), in flax linen: LayerNormMLP, a tanh policy, and critics;
and their layers as NumPy arrays, for `mjx_hopper.faces.export`.

Every module works on any leading batch shape: observations (..., O), actions (..., A).

`dtype` is the hidden layers' computation dtype: jnp.bfloat16 runs their products, LayerNorm
and activations in bfloat16 (LayerNorm's statistics stay float32) on float32 parameters, with
the output layer in float32, so that the outputs (..., A) or (..., atoms) are float32.
"""

from __future__ import annotations

from typing import Any, Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

_INIT = nn.initializers.variance_scaling(1.0, "fan_in", "uniform")


class LayerNormMLP(nn.Module):
  """acme's LayerNormMLP: Dense, LayerNorm, tanh, then an ELU MLP over the other sizes.

  The last layer has no activation unless `activate_final`. Without it, the last layer is an
  output layer: float32 whatever `dtype` is. With `norm_every`, LayerNorm also comes before
  each ELU (FastSAC's critic), not after the first layer alone.
  """

  layer_sizes: Sequence[int]
  activate_final: bool = False
  dtype: Any = jnp.float32
  norm_every: bool = False

  @nn.compact
  def __call__(self, x: jax.Array) -> jax.Array:
    x = nn.Dense(self.layer_sizes[0], kernel_init=_INIT, dtype=self.dtype)(x)
    x = jnp.tanh(nn.LayerNorm(dtype=self.dtype)(x))
    last = len(self.layer_sizes) - 2
    for i, size in enumerate(self.layer_sizes[1:]):
      output = i == last and not self.activate_final
      x = nn.Dense(size, kernel_init=_INIT, dtype=jnp.float32 if output else self.dtype)(x)
      if not output:
        x = nn.elu(nn.LayerNorm(dtype=self.dtype)(x) if self.norm_every else x)
    return x


class TanhPolicy(nn.Module):
  """A deterministic policy: LayerNormMLP(hidden + (A,)) squashed by tanh to the action
  spec [-1, 1] (acme's TanhToSpec). With `squash=False` it returns the pre-tanh outputs."""

  hidden: Sequence[int]
  action_size: int
  dtype: Any = jnp.float32

  @nn.compact
  def __call__(self, obs: jax.Array, squash: bool = True) -> jax.Array:
    pre = LayerNormMLP(tuple(self.hidden) + (self.action_size,), dtype=self.dtype)(obs)
    return jnp.tanh(pre) if squash else pre


class Critic(nn.Module):
  """Q(obs, action) from [obs, clip(action, -1, 1)] (acme's CriticMultiplexer + ClipToSpec).

  With `num_atoms` = 1 it returns a scalar Q of shape (...,); otherwise the (..., num_atoms)
  logits of a categorical distribution over fixed atoms (acme's DiscreteValuedHead).
  `norm_every`: LayerNorm after every hidden layer (LayerNormMLP's).
  """

  hidden: Sequence[int]
  num_atoms: int = 1
  dtype: Any = jnp.float32
  norm_every: bool = False

  @nn.compact
  def __call__(self, obs: jax.Array, action: jax.Array) -> jax.Array:
    x = jnp.concatenate([obs, jnp.clip(action, -1.0, 1.0)], axis=-1)
    if self.num_atoms == 1:
      return LayerNormMLP(tuple(self.hidden) + (1,), dtype=self.dtype,
                          norm_every=self.norm_every)(x)[..., 0]
    x = LayerNormMLP(tuple(self.hidden), activate_final=True, dtype=self.dtype,
                     norm_every=self.norm_every)(x)
    return nn.Dense(self.num_atoms, kernel_init=_INIT, dtype=jnp.float32)(x)


class GaussianPolicy(nn.Module):
  """A diagonal Gaussian policy (acme's MultivariateNormalDiagHead after an activated
  LayerNormMLP). Returns (mean, std), each (..., A): the mean is linear, and the std is
  softplus(linear) scaled so that it starts near `init_scale`, plus `min_scale`."""

  hidden: Sequence[int]
  action_size: int
  init_scale: float = 0.7
  min_scale: float = 1e-6
  dtype: Any = jnp.float32

  @nn.compact
  def __call__(self, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
    x = LayerNormMLP(tuple(self.hidden), activate_final=True, dtype=self.dtype)(obs)
    mean = nn.Dense(self.action_size, kernel_init=_INIT, dtype=jnp.float32)(x)
    raw = nn.Dense(self.action_size, kernel_init=_INIT, dtype=jnp.float32)(x)
    std = nn.softplus(raw) * (self.init_scale / jnp.log(2.0)) + self.min_scale
    return mean, std


# ---- The networks as `export` writes them: NumPy layers that mjx_hopper.faces.export.forward runs

def exported_dense(params: dict, dtype: str, norm: bool, activation: str) -> tuple[dict, dict]:
  """One exported layer: its arrays ("w", "b"), and its structure (the compute dtype, whether
  LayerNorm follows, the activation: "tanh", "elu" or "none")."""
  arrays = {"w": np.asarray(params["kernel"], np.float32),
            "b": np.asarray(params["bias"], np.float32)}
  return arrays, {"dtype": dtype, "norm": norm, "activation": activation}


def exported_mlp(mlp: dict, num_layers: int, activate_final: bool, dtype: str) -> list:
  """The exported layers of a LayerNormMLP of `num_layers` Dense layers: LayerNorm and tanh
  after the first, ELU after the others but an unactivated last one (an output layer, in
  float32)."""
  out = []
  for i in range(num_layers):
    output = i == num_layers - 1 and i > 0 and not activate_final
    arrays, layer = exported_dense(mlp[f"Dense_{i}"], "float32" if output else dtype, i == 0,
                                   "tanh" if i == 0 else "none" if output else "elu")
    if i == 0:
      arrays.update(ln_scale=np.asarray(mlp["LayerNorm_0"]["scale"], np.float32),
                    ln_bias=np.asarray(mlp["LayerNorm_0"]["bias"], np.float32))
    out.append((arrays, layer))
  return out
