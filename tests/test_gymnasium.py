"""The Gymnasium door: the single env passes Gymnasium's checker, both envs give the JAX env's
observations, rewards and flags for the same seed and actions, and bad input is one line."""

import importlib
import subprocess
import sys
import warnings

import jax
import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")
from gymnasium.utils.env_checker import check_env  # noqa: E402
from gymnasium.vector import AutoresetMode  # noqa: E402

from mjx_hopper import envs  # noqa: E402
from mjx_hopper.process import parallel  # noqa: E402

EPISODE_STEPS = 12


@pytest.fixture(scope="module")
def hopper12():
  return envs.make("Hopper", episode_steps=EPISODE_STEPS)


def actions(n_steps, shape, seed=0):
  """Random actions, the last axis' first half at full scale (they fall: termination) and the
  rest at a tenth (they stand: truncation)."""
  a = np.random.default_rng(seed).uniform(-1, 1, (n_steps,) + shape).astype(np.float32)
  if len(shape) == 2:
    a[:, shape[0] // 2:] *= 0.1
  return a


def test_the_single_env_passes_gymnasiums_checker(hopper12):
  env = envs.to_gymnasium(hopper12)
  check_env(env, skip_render_check=True)
  assert isinstance(env, gymnasium.Env)


def test_the_single_env_steps_as_the_jax_env(hopper12, hopper_reset, hopper_step):
  env = envs.to_gymnasium(hopper12)
  obs, _ = env.reset(seed=3)
  # The shared Hopper's programs: its longer episodes step as these until their end.
  state = hopper_reset(jax.random.PRNGKey(3))
  np.testing.assert_allclose(obs, np.asarray(state.obs), rtol=1e-6, atol=1e-6)
  for t, action in enumerate(0.1 * actions(EPISODE_STEPS, (3,))):
    obs, reward, terminated, truncated, info = env.step(action)
    state = hopper_step(state, action)
    assert isinstance(obs, np.ndarray) and obs.dtype == np.float32
    np.testing.assert_allclose(obs, np.asarray(state.obs), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(reward, float(state.reward), rtol=1e-6, atol=1e-6)
    assert set(info["reward_terms"]) == set(envs.REWARD_TERMS)
    assert (terminated, truncated) == (False, t == EPISODE_STEPS - 1)  # a tenth: it stands


@pytest.mark.slow
def test_the_vector_env_steps_as_the_jax_env_and_resets_in_the_same_step(hopper12):
  n = 4
  vec = envs.to_gymnasium(hopper12, num_envs=n)
  assert isinstance(vec, gymnasium.vector.VectorEnv)
  assert vec.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
  assert vec.observation_space.shape == (n, 15) and vec.action_space.shape == (n, 3)
  auto = envs.AutoReset(hopper12)
  state = jax.jit(jax.vmap(auto.reset))(jax.random.split(jax.random.PRNGKey(5), n))
  # Split over the devices as the vector env splits its envs: on jax 0.12, XLA:CPU compiles a
  # program over 2 devices to other last bits than the same per-device code on one device,
  # and the Hopper's contacts grow them past 1e-5 within an episode.
  step = jax.jit(parallel.per_device(jax.vmap(auto.step), n))
  obs, _ = vec.reset(seed=5)
  np.testing.assert_allclose(obs, np.asarray(state.obs), rtol=1e-6, atol=1e-6)
  seen = {"terminated": 0, "truncated": 0}
  for action in actions(2 * EPISODE_STEPS, (n, 3)):
    obs, reward, terminated, truncated, info = vec.step(action)
    state = step(state, action)
    done, truncation = np.asarray(state.done) > 0, np.asarray(state.info["truncation"]) > 0
    np.testing.assert_array_equal(truncated, truncation)
    np.testing.assert_array_equal(terminated, done & ~truncation)
    np.testing.assert_allclose(obs, np.asarray(state.obs), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(reward, np.asarray(state.reward), rtol=1e-5, atol=1e-5)
    if done.any():
      np.testing.assert_array_equal(info["_final_obs"], done)
      np.testing.assert_allclose(np.stack(info["final_obs"][done]),
                                 np.asarray(state.info["final_obs"])[done], rtol=1e-5, atol=1e-5)
    else:
      assert info == {}
    seen["terminated"] += terminated.sum()
    seen["truncated"] += truncated.sum()
  assert seen["terminated"] > 0 and seen["truncated"] > 0


def test_any_task_opens_by_name_path_class_or_instance(hopper12):
  from mjx_hopper.envs import events
  for task in ("Hopper", "mjx_hopper.envs.events:HighJump", events.HighJump, hopper12):
    env = envs.to_gymnasium(task)
    assert env.observation_space.shape == (15,) and env.action_space.shape == (3,)
  assert envs.to_gymnasium(events.HighJump, episode_steps=7).env.episode_steps == 7


def test_bad_input_is_one_line(hopper12):
  env = envs.to_gymnasium(hopper12)
  env.reset(seed=0)
  with pytest.raises(ValueError, match=r"^Hopper takes actions of shape \(3,\), got \(4,\)$"):
    env.step(np.zeros(4))
  vec = envs.to_gymnasium(hopper12, num_envs=2)
  vec.reset(seed=0)
  with pytest.raises(ValueError, match=r"^Hopper takes actions of shape \(2, 3\), got \(3,\)$"):
    vec.step(np.zeros(3))
  with pytest.raises(ValueError, match="num_envs must be None .* got 0"):
    envs.to_gymnasium("Hopper", num_envs=0)
  with pytest.raises(ValueError, match=r"settings \['episode_steps'\] are for a task given by "
                                       "name or class"):
    envs.to_gymnasium(hopper12, episode_steps=5)
  with pytest.raises(ValueError, match="unknown env 'Hoppr'"):
    envs.to_gymnasium("Hoppr")
  with pytest.raises(ValueError, match=r"^Hopper takes finite actions, got nan at index \(1,\)$"):
    env.step(np.array([0.0, np.nan, 0.0]))
  bad = np.zeros((2, 3))
  bad[1, 2], bad[0, 0] = np.inf, np.nan
  with pytest.raises(ValueError, match=r"^Hopper takes finite actions, got nan at index "
                                       r"\(0, 0\) \(and 1 more\)$"):
    vec.step(bad)


def test_the_robots_are_in_gymnasiums_registry(hopper12):
  env = gymnasium.make("mjx_hopper.envs.gymnasium:mjx_hopper/Hopper-v0",
                       episode_steps=EPISODE_STEPS)
  assert env.spec.id == "mjx_hopper/Hopper-v0" and env.unwrapped.env.episode_steps == 12
  assert {f"mjx_hopper/{robot}-v0" for robot in envs.tasks.BUILT_IN} <= set(gymnasium.registry)
  with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    check_env(env.unwrapped)  # with its spec: its render modes and close are checked too
  assert not [w for w in caught if "gymnasium" in w.filename], [str(w.message) for w in caught]
  obs, _ = env.reset(seed=3)
  np.testing.assert_array_equal(obs, envs.to_gymnasium(hopper12).reset(seed=3)[0])
  vec = gymnasium.make_vec("mjx_hopper/Hopper-v0", num_envs=2, episode_steps=EPISODE_STEPS)
  assert isinstance(vec.unwrapped, gymnasium.vector.VectorEnv) and vec.num_envs == 2
  np.testing.assert_array_equal(vec.reset(seed=5)[0],
                                envs.to_gymnasium(hopper12, num_envs=2).reset(seed=5)[0])


def test_importing_the_package_imports_no_gymnasium():
  program = ("import sys; import mjx_hopper, mjx_hopper.envs, mjx_hopper.run.loop; "
             "print('gymnasium' in sys.modules)")
  out = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True,
                       check=True).stdout
  assert out.split() == ["False"]


def test_without_gymnasium_the_error_names_the_extra(monkeypatch):
  monkeypatch.setitem(sys.modules, "gymnasium", None)  # import gymnasium raises ImportError
  monkeypatch.delitem(sys.modules, "mjx_hopper.envs.gymnasium")
  with pytest.raises(ImportError,
                     match=r"in the mjx_hopper checkout, pip install -e '\.\[gymnasium\]'$"):
    importlib.import_module("mjx_hopper.envs.gymnasium")
