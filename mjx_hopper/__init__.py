"""mjx_hopper: PyBullet's locomotion tasks on MuJoCo MJX, and JAX RL agents that learn them.

Importing it sets nothing outside it: `setup()` sets what it needs process-wide."""

from mjx_hopper.process.runtime import cpu_key, setup, xla_flags_with_cpu_devices

__version__ = "0.3.0"
__all__ = ["cpu_key", "setup", "xla_flags_with_cpu_devices"]

