"""Test set-up: two XLA CPU devices (so batches are sharded), and a persistent compile cache."""

import os

os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                           + " --xla_force_host_platform_device_count=2")

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_compilation_cache_dir",
                  os.path.join(os.path.dirname(__file__), "..", ".cache", "jax"))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)


@pytest.fixture(scope="session")
def hopper():
  from mjx_hopper import envs
  return envs.make("Hopper")


@pytest.fixture(scope="session")
def bullet_hopper():
  from mjx_hopper.envs import pybullet_oracle
  return pybullet_oracle.make("Hopper")


@pytest.fixture(scope="session")
def hopper_reset(hopper):
  return jax.jit(hopper.reset)


@pytest.fixture(scope="session")
def hopper_step(hopper):
  return jax.jit(hopper.step)
