"""mjx_hopper: PyBullet's locomotion tasks on MuJoCo MJX, and JAX RL agents that learn them."""

import contextlib
import hashlib
import os
import platform
import sys
import tempfile
import threading

# Headless rendering: MuJoCo picks its OpenGL backend when it is first imported.
os.environ.setdefault("MUJOCO_GL", "egl")

# On a GPU, matrix products through cuBLAS instead of XLA's Triton GEMM fusions: the gpu
# preset's training chunk then compiles in 15 s instead of 28 on an H100 (most of the rest was
# autotuning Triton's kernels), and runs as fast (docs/benchmark-history.md, "Hopper's first
# minute"). XLA reads XLA_FLAGS when JAX starts its
# first backend, so this holds where mjx_hopper is imported before any JAX computation; a
# setting of the flag in XLA_FLAGS wins.
# CPUs ignore it.
if "xla_gpu_enable_triton_gemm" not in os.environ.get("XLA_FLAGS", ""):
  os.environ["XLA_FLAGS"] = " ".join(
      [os.environ.get("XLA_FLAGS", ""), "--xla_gpu_enable_triton_gemm=false"]).strip()

__version__ = "0.2.0"


def xla_flags_with_cpu_devices(count: int) -> str:
  """$XLA_FLAGS with XLA:CPU split into `count` devices (replacing any count it sets); for a
  process to set before JAX starts its backends, or to give a process it starts."""
  flag = "--xla_force_host_platform_device_count"
  kept = [f for f in os.environ.get("XLA_FLAGS", "").split() if not f.startswith(flag)]
  return " ".join(kept + [f"{flag}={count}"])


def _cpu_features() -> str:
  """The host CPU's instruction-set features as the kernel reports them (Linux: the flags of
  /proc/cpuinfo, which come from cpuid, as LLVM's host-feature detection does), else what
  `platform` knows of the processor."""
  try:
    with open("/proc/cpuinfo") as f:
      for line in f:
        name, _, value = line.partition(":")
        if name.strip() in ("flags", "Features"):  # x86-64, arm64
          return " ".join(sorted(value.split()))
  except OSError:
    pass
  return platform.processor()


def cpu_key() -> str:
  """A short name for the code this host's CPU can run: its architecture and a hash of its
  instruction-set features, e.g. 'x86_64-3f2a9c1d0b7e'."""
  digest = hashlib.sha256(_cpu_features().encode()).hexdigest()[:12]
  return f"{platform.machine() or 'cpu'}-{digest}"


def use_compile_cache(directory: str | None = None) -> str:
  """Keeps JAX's compiled programs on disk, so that a rerun, or a new process with the same
  programs, skips most of their compile time. The base directory is `directory`, else
  $MJX_HOPPER_JAX_CACHE, else ~/.cache/mjx_hopper/jax; the programs go to its subfolder named
  by `cpu_key()`, which is returned.

  Why the subfolder: JAX's own cache key leaves out the CPU's features, and XLA:CPU loads a
  cached program compiled for another CPU with only a log line (a program using AVX-512 would
  then stop with SIGILL on a CPU without it). One folder per feature set means a program is
  only ever loaded on a CPU like the one that compiled it."""
  import jax
  base = directory or os.environ.get(
      "MJX_HOPPER_JAX_CACHE", os.path.join(os.path.expanduser("~"), ".cache", "mjx_hopper", "jax"))
  keyed = os.path.join(base, cpu_key())
  jax.config.update("jax_compilation_cache_dir", keyed)
  jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
  _quiet_cache_loads()
  return keyed


# What XLA logs when it loads a cached program, that no user can act on: jaxlib 0.9's CPU loader
# reports the tuning preferences it adds itself on AVX-512 hosts (+prefer-no-gather and
# +prefer-no-scatter, which no host lists among its features) as missing CPU features, and PjRt
# says that it does not version executables. Any other line, a real missing feature included,
# is shown as it is.
HARMLESS_LOAD_LINES = ("Target machine feature +prefer-no-",
                       "Assume version compatibility. PjRt-IFRT does not track")
_STDERR_LOCK = threading.Lock()


@contextlib.contextmanager
def _stderr_without(patterns: tuple[str, ...]):
  """Runs the block with file descriptor 2 (C++ logs write there) captured, then writes back
  what it got, less the lines that contain one of `patterns`. One block at a time."""
  with _STDERR_LOCK, tempfile.TemporaryFile() as capture:
    sys.stderr.flush()
    saved = os.dup(2)
    os.dup2(capture.fileno(), 2)
    try:
      yield
    finally:
      sys.stderr.flush()
      os.dup2(saved, 2)
      os.close(saved)
      capture.seek(0)
      lines = capture.read().splitlines(keepends=True)
      os.write(2, b"".join(line for line in lines
                           if not any(p.encode() in line for p in patterns)))


def _quiet_cache_loads() -> None:
  """Keeps HARMLESS_LOAD_LINES out of the output of JAX's persistent-cache loads (once)."""
  try:
    from jax._src import compilation_cache
    load = compilation_cache.get_executable_and_time
  except (ImportError, AttributeError):  # another JAX: its lines are shown
    return
  if getattr(load, "quiet", False):
    return

  def quiet_load(*args, **kwargs):
    with _stderr_without(HARMLESS_LOAD_LINES):
      return load(*args, **kwargs)

  quiet_load.quiet = True
  compilation_cache.get_executable_and_time = quiet_load
