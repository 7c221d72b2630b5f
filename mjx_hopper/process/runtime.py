"""What mjx_hopper sets for the whole process, in one function: `setup`. Importing the package
sets nothing."""

from __future__ import annotations

import hashlib
import importlib.metadata
import os
import platform

DEVICES_FLAG = "--xla_force_host_platform_device_count"
# The jax versions whose Shardy partitioner crashes compiling our programs over several devices,
# from the first up to the second, excluded; XLA's GSPMD partitioner compiles them. Elsewhere
# Shardy, JAX's default and GSPMD's successor, stays on.
SHARDY_CRASHES = ((0, 11), (0, 12))


def setup(compile_cache: str | None = None, cpu_devices: int | None = None) -> str:
  """Sets what mjx_hopper needs process-wide; calling it again changes nothing more.

  Before JAX starts its backends (else left as they are): MuJoCo's EGL rendering on Linux
  without a display, cuBLAS rather than Triton for a GPU's matrix products, XLA:CPU's own
  kernels rather than YNNPACK's for a CPU's, XLA's CPU split into `cpu_devices` devices (None:
  one per core, unless $XLA_FLAGS sets a count), and where this JAX's Shardy crashes
  (`SHARDY_CRASHES`), XLA's C++ log at errors. Then JAX's config: the persistent compile cache,
  keeping every program, in `compile_cache` (None: the folder already set, else
  $MJX_HOPPER_JAX_CACHE, else ~/.cache/mjx_hopper/jax) per `cpu_key()`, GSPMD where Shardy
  crashes, gloo's CPU collectives where none is chosen, and the compile ledger's listeners
  (which write only while $MJX_HOPPER_COMPILE_LEDGER names a file). Unset environment
  variables only are set. Returns the compile cache's folder. A `cpu_devices` that JAX's
  started backends do not have is a ValueError."""
  if cpu_devices is not None and cpu_devices < 1:
    raise ValueError(f"cpu_devices must be >= 1, got {cpu_devices}")
  from mjx_hopper.process import jax_private, ledger  # import no JAX
  started = jax_private.backends_started()
  if not started:
    os.environ.update(settings_before_start(platform.system(), os.environ, cpu_devices))
  import jax
  if started and cpu_devices is not None and len(jax.devices("cpu")) != cpu_devices:
    raise ValueError(f"cpu_devices={cpu_devices}, but JAX started its backends before "
                     f"mjx_hopper.setup with {len(jax.devices('cpu'))} CPU device(s): call "
                     "setup first")
  directory = jax.config.jax_compilation_cache_dir if compile_cache is None else None
  if directory is None:
    base = compile_cache or os.environ.get("MJX_HOPPER_JAX_CACHE", os.path.join(
        os.path.expanduser("~"), ".cache", "mjx_hopper", "jax"))
    directory = os.path.join(base, cpu_key())
  jax.config.update("jax_compilation_cache_dir", directory)
  jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
  if _shardy_crashes() and "JAX_USE_SHARDY_PARTITIONER" not in os.environ:
    jax.config.update("jax_use_shardy_partitioner", False)
  if jax.config.jax_cpu_collectives_implementation is None:
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
  ledger.start()
  return directory


def compile_cache_over_processes() -> None:
  """Once JAX's distributed runtime has started (`distributed.join`): over processes on CPUs,
  the compile cache off, so that every process compiles every program. Processes other than 0
  never load from it on CPUs (docs/upstream.md), so process 0's loads won little, and on jax
  0.12.1 the program it loaded paired its all-gathers wrongly with one that process 1
  compiled: both hung at a sweep's first evaluation."""
  import jax
  if jax.process_count() > 1 and jax.default_backend() == "cpu":
    jax.config.update("jax_enable_compilation_cache", False)


def settings_before_start(system: str, environ, cpu_devices: int | None = None
                          ) -> dict[str, str]:
  """The environment variables `setup` sets before JAX and MuJoCo start, for `system` (as
  `platform.system()` names it) and the current `environ`: values already set win, but for the
  CPU's device count where `cpu_devices` is given."""
  out = {}
  flags = environ.get("XLA_FLAGS", "")
  if cpu_devices is not None or DEVICES_FLAG not in flags:
    flags = xla_flags_with_cpu_devices(cpu_devices or os.cpu_count() or 1, flags)
  if system == "Linux":
    if ("MUJOCO_GL" not in environ and not environ.get("DISPLAY")
        and not environ.get("WAYLAND_DISPLAY")):
      out["MUJOCO_GL"] = "egl"
    if "xla_gpu_enable_triton_gemm" not in flags:  # cuBLAS: compiles much faster, runs as fast
      flags = f"{flags} --xla_gpu_enable_triton_gemm=false".strip()
  if "xla_cpu_experimental_ynn_fusion_type" not in flags:
    # XLA:CPU's own kernels for matrix products, not YNNPACK's fusions: the CPU chunk runs
    # faster (benchmarks/results/cpu_iteration_*.json), and compiles no slower.
    flags = f"{flags} --xla_cpu_experimental_ynn_fusion_type=".strip()
  if flags != environ.get("XLA_FLAGS", ""):
    out["XLA_FLAGS"] = flags
  if _shardy_crashes() and "TF_CPP_MIN_LOG_LEVEL" not in environ:
    out["TF_CPP_MIN_LOG_LEVEL"] = "2"  # GSPMD warns at every compile that it is deprecated
  return out


def _shardy_crashes(version: str | None = None) -> bool:
  """Whether JAX `version` (default: the installed one, read without importing JAX) is one
  whose Shardy crashes on our programs."""
  first, fixed = SHARDY_CRASHES
  major_minor = tuple(int(p) for p in (version or importlib.metadata.version("jax")).split(".")[:2])
  return first <= major_minor < fixed


def xla_flags_with_cpu_devices(count: int, flags: str | None = None) -> str:
  """`flags` (default $XLA_FLAGS) with XLA:CPU split into `count` devices, replacing any count
  it sets: for `setup`, or for a process to be started."""
  flags = os.environ.get("XLA_FLAGS", "") if flags is None else flags
  mine = f"{DEVICES_FLAG}={count}"
  if DEVICES_FLAG not in flags:
    return f"{flags} {mine}".strip()
  return " ".join(mine if f.startswith(DEVICES_FLAG) else f for f in flags.split())


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
  instruction-set features, e.g. 'x86_64-3f2a9c1d0b7e'. The compile cache keeps a folder per
  key: JAX's cache key leaves out the CPU's features, and XLA:CPU would load a program
  compiled for another CPU (one using AVX-512 then stops with SIGILL)."""
  digest = hashlib.sha256(_cpu_features().encode()).hexdigest()[:12]
  return f"{platform.machine() or 'cpu'}-{digest}"
