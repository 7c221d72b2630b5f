"""mjx_hopper: PyBullet's locomotion tasks on MuJoCo MJX, and JAX RL agents that learn them."""

import hashlib
import os
import platform

from mjx_hopper import compat as _compat


def _settings_before_start(system: str, environ) -> dict[str, str]:
  """The environment variables the package sets on import, because MuJoCo and XLA read them
  once, when they start: MuJoCo's EGL backend for headless rendering on Linux without a display
  (`system` as `platform.system()` names it), and on a GPU, matrix products through cuBLAS
  rather than XLA's Triton GEMMs, which compile much faster and run as fast. Set values win."""
  if system != "Linux":
    return {}
  out = {}
  if ("MUJOCO_GL" not in environ and not environ.get("DISPLAY")
      and not environ.get("WAYLAND_DISPLAY")):
    out["MUJOCO_GL"] = "egl"
  flags = environ.get("XLA_FLAGS", "")
  if "xla_gpu_enable_triton_gemm" not in flags:
    out["XLA_FLAGS"] = f"{flags} --xla_gpu_enable_triton_gemm=false".strip()
  return out


os.environ.update(_settings_before_start(platform.system(), os.environ))

__version__ = "0.2.0"

_compat.install_module_paths()  # the old module paths (mjx_hopper.compat.MODULES)


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
  """Keeps JAX's compiled programs on disk, in `directory` (else $MJX_HOPPER_JAX_CACHE, else
  ~/.cache/mjx_hopper/jax), in a subfolder per `cpu_key()`, which is returned.

  JAX's cache key leaves out the CPU's features, and XLA:CPU would load a program compiled for
  another CPU (one using AVX-512 then stops with SIGILL): one folder per feature set prevents
  it."""
  import jax
  base = directory or os.environ.get(
      "MJX_HOPPER_JAX_CACHE", os.path.join(os.path.expanduser("~"), ".cache", "mjx_hopper", "jax"))
  keyed = os.path.join(base, cpu_key())
  jax.config.update("jax_compilation_cache_dir", keyed)
  jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
  from mjx_hopper import jax_private
  jax_private.quiet_cache_loads()
  return keyed
