"""mjx_hopper: PyBullet's locomotion tasks on MuJoCo MJX, and JAX RL agents that learn them."""

import os

# Headless rendering: MuJoCo picks its OpenGL backend when it is first imported.
os.environ.setdefault("MUJOCO_GL", "egl")

__version__ = "0.1.0"


def use_compile_cache(directory: str | None = None) -> str:
  """Keeps JAX's compiled programs on disk, so that a rerun, or a new process with the same
  programs, skips most of their compile time. The directory is `directory`, else
  $MJX_HOPPER_JAX_CACHE, else ~/.cache/mjx_hopper/jax; it is returned."""
  import jax
  directory = directory or os.environ.get(
      "MJX_HOPPER_JAX_CACHE", os.path.join(os.path.expanduser("~"), ".cache", "mjx_hopper", "jax"))
  jax.config.update("jax_compilation_cache_dir", directory)
  jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
  return directory
