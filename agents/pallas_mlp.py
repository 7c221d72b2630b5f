"""A LayerNormMLP (networks.py: Dense, LayerNorm, tanh, then ELU layers, then a linear output)
as two Pallas kernels on Triton, forward and backward, joined by `jax.custom_vjp`.

Each program takes a tile of batch rows through every layer, so the activations between layers
stay in the chip's caches and a network costs two launches. The price is that every program
streams every weight from the L2 cache: at the presets' widths the weights exceed a
multiprocessor's shared memory, so that traffic, not the products, bounds the kernels. The
weight gradients, which sum over the batch, are XLA's products of what the backward kernel
leaves; each program sums its own rows of the bias and LayerNorm gradients.

On a CPU the kernels run in Pallas's interpret mode: slow, but the same program, for tests.
"""

from __future__ import annotations

import functools
import os
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax.experimental import pallas as pl

_EPS = 1e-6  # flax LayerNorm's


class Tiles(NamedTuple):
  """How the kernels cut the work: batch rows per program, features per product step, and
  Triton's warps and pipeline stages."""
  rows: int
  block: int
  num_warps: int
  num_stages: int


# The fastest measured per compute dtype (the fused learner's tile sweeps, commit b6638f1); float32's
# products stage twice the bytes, so fewer pipeline stages fit in shared memory.
DEFAULT_TILES = {"bfloat16": Tiles(32, 128, 4, 3), "float32": Tiles(32, 128, 8, 2)}


def tiles_from_env(dtype: str = "float32") -> Tiles:
  """$MJX_HOPPER_TILES ("rows,block,num_warps,num_stages") if set, else DEFAULT_TILES[dtype]."""
  text = os.environ.get("MJX_HOPPER_TILES")
  if not text:
    return DEFAULT_TILES[dtype]
  values = [int(v) for v in text.split(",")]
  if len(values) != 4 or any(v < 1 or v & (v - 1) for v in values[:2]):
    raise ValueError(f"MJX_HOPPER_TILES must be 4 integers rows,block,num_warps,num_stages "
                     f"with rows and block powers of 2, got {text!r}")
  return Tiles(*values)


def _padded(n: int) -> int:
  """n rounded up to a power of 2 of at least 16 (Triton's smallest product)."""
  return max(16, 1 << (n - 1).bit_length())


def _pad(x, shape):
  return jnp.pad(x, [(0, s - d) for s, d in zip(shape, x.shape)])


class _Spec(NamedTuple):
  """What shapes a network's kernels (hashable, static). sizes: the padded widths of the input
  and of each dense layer's output; real: the unpadded ones."""
  sizes: tuple[int, ...]
  real: tuple[int, ...]
  dtype: str
  tiles: Tiles
  interpret: bool


def _dot(a, b, transpose_b=False):
  dims = (((1,), (1,)) if transpose_b else ((1,), (0,)), ((), ()))
  return jax.lax.dot_general(a, b, dims, preferred_element_type=jnp.float32)


def _elu(z):
  return jnp.where(z > 0, z, jnp.expm1(jnp.minimum(z, 0.0)))


def _elu_slope(h):
  """ELU's derivative at z, from h = ELU(z)."""
  return jnp.where(h > 0, 1.0, h + 1.0)


def _layer_dtype(spec, i):
  """Dense layer i's product dtype: the compute dtype, but float32 for the output layer."""
  return jnp.float32 if i == len(spec.sizes) - 2 else jnp.dtype(spec.dtype)


def _rows_product(spec, src, w, n0, nb, k_size, dtype, transpose=False):
  """(rows, nb) float32: this program's rows of src[:, :k_size] times columns n0:n0+nb of w
  (or, transposed, of w's rows n0:n0+nb), summed over k in blocks."""
  kb = min(spec.tiles.block, k_size)

  def step(k, acc):
    k0 = pl.multiple_of(k * kb, kb)
    a = src[:, pl.ds(k0, kb)].astype(dtype)
    if transpose:
      return acc + _dot(a, w[pl.ds(n0, nb), pl.ds(k0, kb)].astype(dtype), transpose_b=True)
    return acc + _dot(a, w[pl.ds(k0, kb), pl.ds(n0, nb)].astype(dtype))
  return jax.lax.fori_loop(0, k_size // kb, step,
                           jnp.zeros((spec.tiles.rows, nb), jnp.float32))


def _over_blocks(width, nb, body, carry):
  """body(n0, carry) for each block of nb of `width` features."""
  return jax.lax.fori_loop(0, width // nb,
                           lambda n, c: body(pl.multiple_of(n * nb, nb), c), carry)


def _barrier(spec):
  """Makes this program's stores visible to all its threads before it reads them back."""
  if not spec.interpret:
    from jax.experimental.pallas import triton as pltriton
    pltriton.debug_barrier()


def _forward_kernel(spec, save, *refs):
  layers = len(spec.sizes) - 1
  x, refs = refs[0], refs[1:]
  w, b, refs = refs[:2 * layers:2], refs[1:2 * layers:2], refs[2 * layers:]
  gamma, beta, out, refs = refs[0], refs[1], refs[2], refs[3:]
  h, refs = refs[:layers - 1], refs[layers - 1:]
  xhat, rstd = refs if save else (None, None)
  rows, cd = spec.tiles.rows, jnp.dtype(spec.dtype)
  width = spec.sizes[1]
  nb = min(spec.tiles.block, width)
  inputs = x[...].astype(cd)

  def first(n0):
    return _dot(inputs, w[0][:, pl.ds(n0, nb)].astype(cd)) + b[0][pl.ds(n0, nb)][None, :]

  def moments(n0, sums):
    z = first(n0)
    return sums[0] + z.sum(axis=1), sums[1] + (z * z).sum(axis=1)
  zero = jnp.zeros((rows,), jnp.float32)
  s1, s2 = _over_blocks(width, nb, moments, (zero, zero))
  mean = s1 / spec.real[1]
  inv = jax.lax.rsqrt(jnp.maximum(s2 / spec.real[1] - mean * mean, 0.0) + _EPS)

  def normalize(n0, carry):
    xh = (first(n0) - mean[:, None]) * inv[:, None]
    y = xh * gamma[pl.ds(n0, nb)][None, :] + beta[pl.ds(n0, nb)][None, :]
    h[0][:, pl.ds(n0, nb)] = jnp.tanh(y).astype(h[0].dtype)
    if save:
      xhat[:, pl.ds(n0, nb)] = xh
    return carry
  _over_blocks(width, nb, normalize, 0)
  if save:
    rstd[...] = inv

  for i in range(1, layers):
    _barrier(spec)
    hidden = i < layers - 1
    dst = h[i] if hidden else out
    nbi = min(spec.tiles.block, spec.sizes[i + 1])

    def dense(n0, carry, i=i, dst=dst, nbi=nbi, hidden=hidden):
      z = _rows_product(spec, h[i - 1], w[i], n0, nbi, spec.sizes[i], _layer_dtype(spec, i))
      z = z + b[i][pl.ds(n0, nbi)][None, :]
      dst[:, pl.ds(n0, nbi)] = (_elu(z) if hidden else z).astype(dst.dtype)
      return carry
    _over_blocks(spec.sizes[i + 1], nbi, dense, 0)


def _backward_kernel(spec, *refs):
  layers = len(spec.sizes) - 1
  dout, refs = refs[0], refs[1:]
  h, refs = refs[:layers - 1], refs[layers - 1:]
  xhat, rstd, refs = refs[0], refs[1], refs[2:]
  w, refs = refs[:layers], refs[layers:]
  gamma, dy0, refs = refs[0], refs[1], refs[2:]
  dz, dx, refs = refs[:layers - 1], refs[layers - 1], refs[layers:]
  # This program's sums over its rows, of each hidden layer's bias gradient and LayerNorm's.
  d_bias, d_gamma, d_beta = refs[:layers - 1], refs[layers - 1], refs[layers]
  rows, cd = spec.tiles.rows, jnp.dtype(spec.dtype)

  def upstream(i):  # the gradient at dense layer i's pre-activations
    return dout if i == layers - 1 else dz[i]

  for i in range(layers - 2, 0, -1):  # the ELU layers, top down
    nb = min(spec.tiles.block, spec.sizes[i + 1])

    def elu_layer(n0, carry, i=i, nb=nb):
      dh = _rows_product(spec, upstream(i + 1), w[i + 1], n0, nb, spec.sizes[i + 2],
                         _layer_dtype(spec, i + 1), transpose=True)
      slope = _elu_slope(h[i][:, pl.ds(n0, nb)].astype(jnp.float32))
      d = dh * slope
      dz[i][:, pl.ds(n0, nb)] = d.astype(dz[i].dtype)
      d_bias[i][:, pl.ds(n0, nb)] = d.sum(axis=0)[None, :]
      return carry
    _over_blocks(spec.sizes[i + 1], nb, elu_layer, 0)
    _barrier(spec)

  width = spec.sizes[1]
  nb = min(spec.tiles.block, width)

  def tanh_and_scale(n0, sums):
    dh = _rows_product(spec, upstream(1), w[1], n0, nb, spec.sizes[2], _layer_dtype(spec, 1),
                       transpose=True)
    h0 = h[0][:, pl.ds(n0, nb)].astype(jnp.float32)
    dy = dh * (1.0 - h0 * h0)
    dy0[:, pl.ds(n0, nb)] = dy
    dxh = dy * gamma[pl.ds(n0, nb)][None, :]
    xh = xhat[:, pl.ds(n0, nb)]
    d_beta[:, pl.ds(n0, nb)] = dy.sum(axis=0)[None, :]
    d_gamma[:, pl.ds(n0, nb)] = (dy * xh).sum(axis=0)[None, :]
    return sums[0] + dxh.sum(axis=1), sums[1] + (dxh * xh).sum(axis=1)
  zero = jnp.zeros((rows,), jnp.float32)
  a1, a2 = _over_blocks(width, nb, tanh_and_scale, (zero, zero))
  a1, a2 = a1 / spec.real[1], a2 / spec.real[1]
  inv = rstd[...]
  _barrier(spec)

  def normalization(n0, dx_acc):
    dxh = dy0[:, pl.ds(n0, nb)] * gamma[pl.ds(n0, nb)][None, :]
    xh = xhat[:, pl.ds(n0, nb)]
    real = (n0 + jax.lax.broadcasted_iota(jnp.int32, (1, nb), 1)) < spec.real[1]
    d = jnp.where(real, inv[:, None] * (dxh - a1[:, None] - xh * a2[:, None]), 0.0)
    dz[0][:, pl.ds(n0, nb)] = d.astype(dz[0].dtype)
    d_bias[0][:, pl.ds(n0, nb)] = d.sum(axis=0)[None, :]
    return dx_acc + _dot(d.astype(cd), w[0][:, pl.ds(n0, nb)].astype(cd), transpose_b=True)
  dx[...] = _over_blocks(width, nb, normalization,
                         jnp.zeros((rows, spec.sizes[0]), jnp.float32))


def _call(spec, kernel, inputs, outputs, rows_in, per_program=0):
  """pallas_call over tiles of batch rows. rows_in[j]: whether input j is split by rows
  (else whole); outputs are split by rows, but for the last `per_program`, of one row per
  program."""
  rows = spec.tiles.rows
  batch = inputs[0].shape[0]

  def whole(x):
    return pl.BlockSpec(x.shape, lambda i, n=x.ndim: (0,) * n)

  def by_rows(shape):
    return pl.BlockSpec((rows,) + tuple(shape[1:]),
                        lambda i, n=len(shape): (i,) + (0,) * (n - 1))
  kwargs = {}
  if not spec.interpret:
    from jax.experimental.pallas import triton as pltriton
    kwargs["compiler_params"] = pltriton.CompilerParams(num_warps=spec.tiles.num_warps,
                                                         num_stages=spec.tiles.num_stages)
  split = len(outputs) - per_program
  out_specs = [by_rows(o.shape) for o in outputs[:split]]
  out_specs += [pl.BlockSpec((1,) + o.shape[1:], lambda i: (i, 0)) for o in outputs[split:]]
  return pl.pallas_call(
      kernel, out_shape=outputs, grid=(batch // rows,),
      in_specs=[by_rows(x.shape) if r else whole(x) for x, r in zip(inputs, rows_in)],
      out_specs=out_specs, interpret=spec.interpret, **kwargs)(*inputs)


def _prepare(spec, params, x):
  """The inputs padded to the kernels' shapes: x (batch rows, sizes[0]), weights, biases,
  LayerNorm's scale and offset."""
  kernels, biases, gamma, beta = params
  batch = -(-x.shape[0] // spec.tiles.rows) * spec.tiles.rows
  cd = jnp.dtype(spec.dtype)
  ws = tuple(_pad(k, spec.sizes[i:i + 2]).astype(_layer_dtype(spec, i))
             for i, k in enumerate(kernels))
  bs = tuple(_pad(b.astype(jnp.float32), spec.sizes[i + 1:i + 2]) for i, b in enumerate(biases))
  return (_pad(x.astype(cd), (batch, spec.sizes[0])), ws, bs,
          _pad(gamma.astype(jnp.float32), spec.sizes[1:2]),
          _pad(beta.astype(jnp.float32), spec.sizes[1:2]))


def _forward(spec, params, x, save):
  xp, ws, bs, gamma, beta = _prepare(spec, params, x)
  batch, cd = xp.shape[0], jnp.dtype(spec.dtype)
  layers = len(ws)
  outputs = [jax.ShapeDtypeStruct((batch, spec.sizes[-1]), jnp.float32)]
  outputs += [jax.ShapeDtypeStruct((batch, s), cd) for s in spec.sizes[1:-1]]
  if save:
    outputs += [jax.ShapeDtypeStruct((batch, spec.sizes[1]), jnp.float32),
                jax.ShapeDtypeStruct((batch,), jnp.float32)]
  inputs = [xp] + [a for pair in zip(ws, bs) for a in pair] + [gamma, beta]
  results = _call(spec, functools.partial(_forward_kernel, spec, save), inputs, outputs,
                  [True] + [False] * (2 * layers + 2))
  out = results[0][:x.shape[0], :spec.real[-1]]
  return out, (xp, ws, gamma, results[1:layers], results[layers:])


@functools.partial(jax.custom_vjp, nondiff_argnums=(0,))
def _mlp(spec, params, x):
  return _forward(spec, params, x, save=False)[0]


def _mlp_fwd(spec, params, x):
  out, saved = _forward(spec, params, x, save=True)
  return out, saved


def _mlp_bwd(spec, saved, dout):
  xp, ws, gamma, hs, (xhat, rstd) = saved
  batch, cd, layers = xp.shape[0], jnp.dtype(spec.dtype), len(ws)
  dout_p = _pad(dout.astype(jnp.float32), (batch, spec.sizes[-1]))
  outputs = [jax.ShapeDtypeStruct((batch, spec.sizes[1]), jnp.float32)]
  outputs += [jax.ShapeDtypeStruct((batch, s), cd) for s in spec.sizes[1:-1]]
  outputs += [jax.ShapeDtypeStruct((batch, spec.sizes[0]), jnp.float32)]
  programs = batch // spec.tiles.rows
  sums = [jax.ShapeDtypeStruct((programs, s), jnp.float32) for s in spec.sizes[1:-1]]
  sums += [jax.ShapeDtypeStruct((programs, spec.sizes[1]), jnp.float32)] * 2
  inputs = [dout_p, *hs, xhat, rstd, *ws, gamma]
  results = _call(spec, functools.partial(_backward_kernel, spec), inputs, outputs + sums,
                  [True] * (layers + 2) + [False] * (layers + 1), per_program=len(sums))
  dy0, dz, dx = results[0], list(results[1:layers]), results[layers]
  sums = [s.sum(0) for s in results[layers + 1:]]
  dz.append(dout_p)
  below = [xp] + list(hs)  # each dense layer's input

  def product(a, d, i):
    dtype = _layer_dtype(spec, i)
    return jnp.einsum("bk,bn->kn", a.astype(dtype), d.astype(dtype),
                      preferred_element_type=jnp.float32)
  real = spec.real
  d_kernels = tuple(product(below[i], dz[i], i)[:real[i], :real[i + 1]] for i in range(layers))
  d_biases = tuple(s[:r] for s, r in zip(sums[:layers - 1] + [dout_p.sum(0)], real[1:]))
  d_gamma, d_beta = sums[-2][:real[1]], sums[-1][:real[1]]
  n = dout.shape[0]
  return (d_kernels, d_biases, d_gamma, d_beta), dx[:n, :real[0]]


_mlp.defvjp(_mlp_fwd, _mlp_bwd)


def mlp(params, x, dtype: str = "float32", tiles: Tiles | None = None,
        interpret: bool | None = None):
  """A LayerNormMLP with a linear output layer, fused: (..., K) -> (..., N) float32.

  `params`: (kernels, biases, LayerNorm's scale, LayerNorm's offset), as fused.py reads them
  from a flax LayerNormMLP; `dtype` is the hidden layers' compute dtype.
  `interpret` defaults to Pallas's interpret mode off a GPU.
  """
  kernels = params[0]
  real = (kernels[0].shape[0],) + tuple(k.shape[1] for k in kernels)
  if len(kernels) < 2:
    raise ValueError(f"a fused LayerNormMLP needs a hidden and an output layer, got "
                     f"{len(kernels)} layer(s)")
  if interpret is None:
    interpret = jax.default_backend() != "gpu"
  dtype = jnp.dtype(dtype).name
  spec = _Spec(tuple(_padded(n) for n in real), real, dtype, tiles or tiles_from_env(dtype),
               interpret)
  lead = x.shape[:-1]
  out = _mlp(spec, params, x.reshape(-1, x.shape[-1]))
  return out.reshape(lead + (real[-1],))
