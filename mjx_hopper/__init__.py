"""mjx_hopper: PyBullet's locomotion tasks on MuJoCo MJX, and JAX RL agents that learn them."""

import os

# Headless rendering: MuJoCo picks its OpenGL backend when it is first imported.
os.environ.setdefault("MUJOCO_GL", "egl")

__version__ = "0.1.0"
