"""Programs kept as traced: a jitted function whose traced and lowered program (`jax.export`'s
StableHLO) is written beside the compile cache and read back by a later build, in this process
or another, so that a warm start skips tracing, and the program's compile-cache key no longer
depends on what the process traced before. A program is kept under a hash of everything that
shapes it: the caller's identity of the function, its arguments' paths, shapes, dtypes and
shardings, this package's source, the versions of what it is built on, XLA's flags, JAX's
settings and the devices. Anything else, or an unreadable file, traces the function afresh.
A function without an identity is exported too, in memory only, so that the same code kept or
not compiles to one program, which the compile cache then serves to both (the notebook's
Hopper, a class of its own, and the package's)."""

from __future__ import annotations

import functools
import hashlib
import importlib
import importlib.metadata
import os
import pickle
import sys
import tempfile
import threading

import jax
import numpy as np
from jax import export
from jax.sharding import NamedSharding

FOLDER = "programs"  # under JAX's compile-cache folder
_PACKAGES = ("mjx_hopper", "mjx_hopper.envs", "mjx_hopper.agents")
_VERSIONS = ("jax", "jaxlib", "mujoco", "mujoco-mjx", "brax", "flax", "optax", "numpy")
_SETTINGS = ("jax_enable_x64", "jax_default_matmul_precision", "jax_use_shardy_partitioner",
             "jax_numpy_rank_promotion", "jax_numpy_dtype_promotion", "jax_default_prng_impl",
             "jax_threefry_partitionable")


def jit(fun, identity: str | None, name: str, exported: bool = True, **jit_kwargs):
  """`jax.jit(fun, **jit_kwargs)` through its export, the program kept under `identity` where
  one is given: a text, the same in every process, that names all `fun` closes over besides
  this package's code. Static arguments are refused (the key holds no argument's value).
  exported=False, for a function that calls the host (which `jax.export` cannot serialise):
  `jax.jit`'s function, neither exported nor kept."""
  if {"static_argnums", "static_argnames"} & set(jit_kwargs):
    raise ValueError(f"kept.jit takes no static arguments, got {sorted(jit_kwargs)}")
  if not exported:
    return jax.jit(fun, **jit_kwargs)
  return Kept(jax.jit(fun, **jit_kwargs), identity, name, jit_kwargs)


# The process's programs by key, shared by every Kept of the same identity: a second build of
# the same trainer (a resume, another seed) calls the jitted functions of the first, whose
# compiled programs JAX still holds in memory.
_programs: dict[str, object] = {}
_lock = threading.RLock()


def forget() -> None:
  """Empties the process's programs (the kept files stay): a Kept made after this reads its
  programs from the files, as in a new process."""
  with _lock:
    _programs.clear()


class Kept:
  """A jitted function that is called and lowered as `jax.jit`'s, through its kept program."""

  def __init__(self, jitted, identity: str | None, name: str, jit_kwargs: dict):
    self._jitted, self._identity, self.__name__ = jitted, identity, name
    self._jit_kwargs = jit_kwargs
    self._seen: dict[tuple, object] = {}  # by the arguments' signature: a call's fast path

  def __call__(self, *args):
    return self._program(args)(*args)

  def lower(self, *args):
    """The program for `args` (arrays or shapes) lowered, as `jax.jit(...).lower` lowers."""
    return self._program(args).lower(*args)

  def _program(self, args):
    if not jax.config.jax_use_shardy_partitioner:
      # Under GSPMD (`mjx_hopper.setup`'s choice on JAX 0.11) JAX 0.11.2 writes Shardy's sharding
      # attributes into an export and then refuses to lower the export's call: the function
      # runs as jitted.
      return self._jitted
    leaves, tree = jax.tree.flatten(args)
    signature = (tree, *map(_signature, leaves), *(getattr(jax.config, s) for s in _SETTINGS))
    program = self._seen.get(signature)
    if program is None and self._identity is None:
      program = self._seen[signature] = self._trace(None, args)
    elif program is None:
      key = program_key(self.__name__, self._identity, args, self._jit_kwargs)
      with _lock:
        if key not in _programs:
          _programs[key] = self._read(key) or self._trace(key, args)
        program = self._seen[signature] = _programs[key]
    return program

  def _read(self, key: str):
    path = _path(key)
    if path is None or not os.path.exists(path):
      return None
    try:
      with open(path, "rb") as f:
        saved = pickle.load(f)
      return self._calling(export.deserialize(saved["exported"]), saved["out_tree"])
    except Exception:  # unreadable, or from another pickle: traced afresh and written again
      return None

  def _trace(self, key: str | None, args):
    leaves, in_tree = jax.tree.flatten(args)
    # The outputs' structure, for the flat function's own output shardings; the call inside
    # `flat` reuses this trace.
    out_shape = jax.eval_shape(self._jitted, *args)
    out_tree = jax.tree.structure(out_shape)

    def flat(*leaves):
      return jax.tree.leaves(self._jitted(*jax.tree.unflatten(in_tree, leaves)))
    flat.__name__ = f"kept_{self.__name__}"  # the program traced, as the ledger names it
    avals = [_aval(x) for x in leaves]
    # The flat function with the original's shardings and donation, leaf by leaf: without them
    # at its top, the exported program compiles markedly slower than the function jitted.
    flat_jit = jax.jit(flat, **_flat_kwargs(self._jit_kwargs, args, out_shape))
    try:
      serialized = export.export(flat_jit, platforms=[_platform(avals)])(*avals).serialize()
    except Exception:  # not exportable (a host callback, say): the function as jitted
      return self._jitted
    path = None if key is None else _path(key)
    if path is not None:
      _write(path, {"exported": serialized, "out_tree": out_tree})
    # As read back: this process then compiles what a later one loads from the compile cache.
    return self._calling(export.deserialize(serialized), out_tree)

  def _calling(self, exported, out_tree):
    """A jitted function of the original's arguments that calls `exported`."""
    def call(*args):
      return jax.tree.unflatten(out_tree, exported.call(*jax.tree.leaves(args)))
    call.__name__ = self.__name__
    return jax.jit(call, **self._jit_kwargs)


def _flat_kwargs(jit_kwargs: dict, args: tuple, out_shape) -> dict:
  """`jax.jit`'s options for a function of `args` as leaves: shardings (given as prefixes of the
  arguments and outputs) one per leaf, and donation by the donated arguments' leaves."""
  flat = {k: v for k, v in jit_kwargs.items()
          if k not in ("in_shardings", "out_shardings", "donate_argnums")}
  if "in_shardings" in jit_kwargs:
    flat["in_shardings"] = _per_leaf(jit_kwargs["in_shardings"], args)
  if "out_shardings" in jit_kwargs:
    flat["out_shardings"] = _per_leaf(jit_kwargs["out_shardings"], out_shape)
  if "donate_argnums" in jit_kwargs:
    donated = jit_kwargs["donate_argnums"]
    starts = np.cumsum([0, *(len(jax.tree.leaves(a)) for a in args)]).tolist()
    flat["donate_argnums"] = tuple(i for n in sorted(np.atleast_1d(donated).tolist())
                                   for i in range(starts[n], starts[n + 1]))
  return flat


def _per_leaf(prefix, tree) -> list:
  """The sharding (or None) that `prefix`, a prefix of `tree`, gives each of its leaves."""
  out = []
  jax.tree.map(lambda s, sub: out.extend([s] * len(jax.tree.leaves(sub))), prefix, tree,
               is_leaf=lambda s: s is None or isinstance(s, jax.sharding.Sharding))
  return out


def program_key(name: str, identity: str, args, jit_kwargs: dict) -> str:
  """The hash under which the program of `name` (`identity`) for `args` is kept."""
  parts = [name, identity, repr(sorted((k, repr(v)) for k, v in jit_kwargs.items()
                                       if k not in ("in_shardings", "out_shardings"))),
           _environment()]
  for path, x in jax.tree_util.tree_flatten_with_path(args)[0]:
    aval = _aval(x)
    parts.append(f"{jax.tree_util.keystr(path)} {aval.shape} {aval.dtype} {aval.weak_type} "
                 f"{_sharding_text(aval.sharding)}")
  # The explicit shardings of the function's inputs and outputs, as text.
  for k in ("in_shardings", "out_shardings"):
    if k in jit_kwargs:
      parts.append(repr([_sharding_text(s) for s in jax.tree.leaves(
          jit_kwargs[k], is_leaf=lambda s: isinstance(s, jax.sharding.Sharding))]))
  return hashlib.sha256("\n".join(parts).encode()).hexdigest()


def _signature(x) -> tuple:
  """What of argument `x` shapes a program: (shape, dtype, weak type, sharding over a mesh or
  None), as jit sees it; quick enough for every call."""
  if isinstance(x, (jax.ShapeDtypeStruct, jax.Array)):
    sharding = getattr(x, "sharding", None)
    return (x.shape, x.dtype, getattr(x, "weak_type", False),
            sharding if isinstance(sharding, NamedSharding) else None)
  # Python's numbers are weakly typed, not its bools.
  return (np.shape(x), jax.dtypes.canonicalize_dtype(np.result_type(x)),
          type(x) in (int, float, complex), None)


def _aval(x) -> jax.ShapeDtypeStruct:
  """`x`'s `_signature` as a shape to trace with."""
  shape, dtype, weak, sharding = _signature(x)
  return jax.ShapeDtypeStruct(shape, dtype, weak_type=weak, sharding=sharding)


def _sharding_text(sharding) -> str:
  if not isinstance(sharding, NamedSharding):
    return "unspecified" if sharding is None else type(sharding).__name__
  mesh = sharding.mesh
  return (f"{dict(zip(mesh.axis_names, mesh.devices.shape))} {sharding.spec} "
          f"{mesh.devices.flat[0].platform} {sharding.memory_kind}")


def _platform(avals) -> str:
  """The platform to export for, as `jax.export` names it: the CPU's where the arguments are on
  the host's CPU devices (a GPU run's evaluation on the host), else the default backend's."""
  for aval in avals:
    if aval.sharding is not None and aval.sharding.mesh.devices.flat[0].platform == "cpu":
      return "cpu"
  return export.default_export_platform()


def _environment() -> str:
  """What shapes every program besides its function and arguments: JAX's settings as they are
  now, XLA's flags as XLA reads them (split at white space: `setup` rewrites $XLA_FLAGS with
  single spaces where the CLI sets a device count), and what a process cannot change."""
  settings = [f"{s} {getattr(jax.config, s, None)}" for s in _SETTINGS]
  return "\n".join([*settings, *os.environ.get("XLA_FLAGS", "").split(), _fixed()])


@functools.cache
def _fixed() -> str:
  """The versions, devices, Python and this package's source."""
  versions = []
  for name in _VERSIONS:
    try:
      versions.append(f"{name} {importlib.metadata.version(name)}")
    except importlib.metadata.PackageNotFoundError:
      versions.append(f"{name} none")
  devices = [f"{d.platform} {d.device_kind}" for d in jax.devices()]
  return "\n".join([*versions, *devices, f"processes {jax.process_count()}", _source_digest(),
                    sys.version])


@functools.cache
def _source_digest() -> str:
  """A hash of this package's source and model files."""
  digest = hashlib.sha256()
  for package in _PACKAGES:
    root = os.path.dirname(importlib.import_module(package).__file__)
    for folder, dirs, files in sorted(os.walk(root)):
      dirs.sort()
      for name in sorted(files):
        if name.endswith((".py", ".xml")):
          with open(os.path.join(folder, name), "rb") as f:
            digest.update(name.encode() + f.read())
  return digest.hexdigest()


def _path(key: str) -> str | None:
  """Where the program of `key` is kept: under JAX's compile cache, or None where it has none."""
  cache = jax.config.jax_compilation_cache_dir
  if not cache or not jax.config.jax_enable_compilation_cache:
    return None
  return os.path.join(cache, FOLDER, f"{key}.pkl")


def _write(path: str, saved: dict) -> None:
  """Writes `saved` to `path` whole or not at all (a program that cannot be written is traced
  again by the next process)."""
  temporary = None
  try:
    os.makedirs(os.path.dirname(path), exist_ok=True)
    fd, temporary = tempfile.mkstemp(dir=os.path.dirname(path), suffix=".tmp")
    with os.fdopen(fd, "wb") as f:
      pickle.dump(saved, f)
    os.replace(temporary, path)
  except Exception:
    if temporary is not None and os.path.exists(temporary):
      os.remove(temporary)
