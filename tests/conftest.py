"""Test set-up: two XLA CPU devices (so batches are sharded), and a persistent compile cache."""

import os

# Two devices; and XLA:CPU's loop emitters instead of its fusion emitters, which compile MJX's
# physics a quarter to a third faster (benchmarks/research/xla_cpu_flags.py), as the suite's time
# is mostly compiling. Users keep XLA's default: the programs' speed depends on the robot
# (docs/benchmark-history.md). And single-threaded matrix products within a device: XLA:CPU
# splits a product over its thread pool only in single-device programs, which changes the
# order of its sums, so a sweep member would not be bit-identical to its single run on one
# device (test_sweep.py).
TEST_XLA_FLAGS = ("--xla_force_host_platform_device_count=2 --xla_cpu_use_fusion_emitters=false "
                  "--xla_cpu_multi_thread_eigen=false")
os.environ["XLA_FLAGS"] = os.environ.get("XLA_FLAGS", "") + " " + TEST_XLA_FLAGS

# One compile cache for the tests and the processes they start (CLI runs, notebooks), so that
# a program compiled by one is loaded by the others.
os.environ.setdefault("MJX_HOPPER_JAX_CACHE",
                      os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".cache", "jax"))

import jax  # noqa: E402
import pytest  # noqa: E402

import mjx_hopper  # noqa: E402

mjx_hopper.use_compile_cache()


ROBOTS = ("Hopper", "Walker2D", "HalfCheetah", "Ant", "Humanoid")
_ENVS, _BULLET = {}, {}


def make_env(env_id):
  """One env per id for the whole session, so compiled functions are shared."""
  from mjx_hopper import envs
  if env_id not in _ENVS:
    _ENVS[env_id] = envs.make(env_id)
  return _ENVS[env_id]


def make_bullet(env_id):
  from mjx_hopper.envs import pybullet_oracle
  if env_id not in _BULLET:
    _BULLET[env_id] = pybullet_oracle.make(env_id)
  return _BULLET[env_id]


@pytest.fixture(scope="session")
def hopper():
  return make_env("Hopper")


@pytest.fixture(scope="session")
def bullet_hopper():
  return make_bullet("Hopper")


@pytest.fixture(scope="session")
def hopper_reset(hopper):
  return jax.jit(hopper.reset)


@pytest.fixture(scope="session")
def hopper_step(hopper):
  return jax.jit(hopper.step)


_EPISODES = {}


def mjx_episodes(env_id, num_episodes=128):
  """Random- and zero-action episode statistics of `env_id`, with the qpos of episode 0, from
  one compiled program per robot (`scale` 1 is random actions, 0 zero actions)."""
  from mjx_hopper import rollout
  if env_id not in _EPISODES:
    env = make_env(env_id)

    @jax.jit
    def run(key, scale):
      random = rollout.random_policy(env.action_size)
      return rollout.episodes(env, lambda obs, k: scale * random(obs, k), key, num_episodes,
                              record_qpos=True)

    _EPISODES[env_id] = {policy: jax.device_get(run(jax.random.PRNGKey(1), scale))
                         for policy, scale in (("random", 1.0), ("zero", 0.0))}
  return _EPISODES[env_id]
