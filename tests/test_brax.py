"""Brax's wrappers and Brax's own PPO trainer on our envs (docs/brax.md; its SAC runs in
test_docs.py, as the page has it).

The trainers run tiny (8 envs, 20-step episodes, 16-unit networks) on conftest's two CPU
devices, so their pmap really splits the envs.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.wrappers import training
from brax.training.agents.ppo import networks as ppo_networks
from brax.training.agents.ppo import train as ppo
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from mjx_hopper import envs

N = 4            # envs in the wrapper tests
LIMIT = 20       # Brax's episode_length in the wrapper tests
# Envs 0 and 1 push every joint to -1 and fall on step 5; envs 2 and 3 hold still (zero
# torque), and fall after 30 steps or more.
ACTIONS = jnp.array([[-1.0, -1.0, -1.0]] * 2 + [[0.0, 0.0, 0.0]] * 2)
EPISODE = 20     # the trainers' episode_length
EVAL_ENVS = 4    # the trainers' evaluation episodes


def device_put_replicated(tree, devices):
  """What `jax.device_put_replicated` did, from public APIs: every leaf (shape S) becomes one
  array of shape (len(devices), *S), one copy on each device. Brax 0.14's trainers call it;
  jax 0.9 deprecates it and jax 0.10 removed it."""
  sharding = NamedSharding(Mesh(np.array(devices), ("replica",)), PartitionSpec("replica"))
  return jax.tree.map(
      lambda x: jax.device_put(jnp.broadcast_to(x, (len(devices),) + jnp.shape(x)), sharding),
      tree)


@pytest.fixture(scope="module")
def brax_trainers():
  """Brax's PPO `train` with the shim installed, for this module's tests (SAC's runs in
  test_docs, as docs/brax.md has it)."""
  with pytest.MonkeyPatch.context() as patch:
    patch.setattr(jax, "device_put_replicated", device_put_replicated, raising=False)
    yield ppo.train


def test_step_keeps_every_key_a_wrapper_added(hopper, hopper_reset):
  state = hopper_reset(jax.random.PRNGKey(0))
  state = state.replace(metrics={**state.metrics, "reward": jnp.zeros(())},
                        info={**state.info, "mine": jnp.zeros((2,))})
  out = jax.eval_shape(hopper.step, state, jnp.zeros(3))  # traces the step, compiles nothing
  assert set(out.metrics) == set(envs.REWARD_TERMS) | {"reward"}
  assert set(out.info) == set(state.info)
  assert jax.tree.structure(out) == jax.tree.structure(state)  # a scan carry, as Brax needs


def first_done(done):
  """(N,) the index of each env's first done step in a (T, N) array of done flags."""
  assert (done > 0).any(0).all(), "an episode did not end"
  return np.argmax(done > 0, axis=0)


@pytest.fixture(scope="module")
def episodes():
  """25 steps of 4 Hoppers (ACTIONS) under Brax's training stack with a 20-step limit, plus
  EvalWrapper; and under Brax's EpisodeWrapper with our AutoReset in place of Brax's.

  The env's own limit is 10 steps, to show that Brax's EpisodeWrapper owns the time limit."""
  env = envs.make("Hopper", episode_steps=10)
  brax_stack = training.EvalWrapper(training.wrap(env, episode_length=LIMIT))
  ours = training.VmapWrapper(envs.AutoReset(training.EpisodeWrapper(env, LIMIT, 1)))

  def rollout(stack, keys):
    def one(state, _):
      state = stack.step(state, ACTIONS)
      return state, state
    first = stack.reset(keys)
    return first, *jax.lax.scan(one, first, None, length=LIMIT + 5)

  @jax.jit
  def run(keys):
    # Our AutoReset splits its key and resets with the second half: the same starts.
    inner = jax.vmap(lambda k: jax.random.split(k)[1])(keys)
    return rollout(brax_stack, inner), rollout(ours, keys)

  return jax.device_get(run(jax.random.split(jax.random.PRNGKey(1), N)))


@pytest.mark.parametrize("stack", ["brax", "our_autoreset"])
def test_brax_episode_wrapper_owns_the_time_limit(episodes, stack):
  first, _, states = episodes[0 if stack == "brax" else 1]
  done, truncation, alive = states.done, states.info["truncation"], states.metrics["alive"]
  end = first_done(done)
  envs_ = np.arange(N)
  # Envs 0 and 1 fall (terminated: alive -1, no truncation); envs 2 and 3 stop at step LIMIT
  # (truncated), not at the env's own limit of 10.
  np.testing.assert_array_equal(end, [4, 4, LIMIT - 1, LIMIT - 1])
  np.testing.assert_array_equal(alive[end, envs_] < 0, [True, True, False, False])
  np.testing.assert_array_equal(truncation[end, envs_], [0, 0, 1, 1])
  for i in envs_:  # the step count, then a new episode
    steps = states.info["steps"][:, i]
    np.testing.assert_array_equal(steps[:end[i]], np.arange(1, end[i] + 1))
    # Brax's AutoResetWrapper starts the count again on the next step; ours on this one.
    assert steps[end[i]] == (end[i] + 1 if stack == "brax" else 0)
    assert steps[end[i] + 1] == 1 and done[end[i] + 1, i] == 0
  if stack == "our_autoreset":
    np.testing.assert_array_equal(states.info["final_obs"][:end[0], 0], states.obs[:end[0], 0])
    assert not np.array_equal(states.info["final_obs"][end[0], 0], states.obs[end[0], 0])
  else:  # Brax's AutoResetWrapper puts each env back to its first observation
    for i in envs_:
      np.testing.assert_array_equal(states.obs[end[i], i], first.obs[i])


def test_eval_wrapper_sums_each_first_episode(episodes):
  _, last, states = episodes[0]
  end = first_done(states.done)
  evaluated = last.info["eval_metrics"]
  np.testing.assert_array_equal(evaluated.episode_steps, end + 1)
  np.testing.assert_array_equal(evaluated.active_episodes, 0)
  for name in ("reward",) + envs.REWARD_TERMS:
    values = states.metrics[name]
    want = [values[:end[i] + 1, i].sum() for i in range(N)]
    np.testing.assert_allclose(evaluated.episode_metrics[name], want, rtol=1e-5, atol=1e-5)
  np.testing.assert_array_equal(states.metrics["reward"], states.reward)


@pytest.mark.slow  # its own programs: a second task under the stack the Hopper's tests cover
def test_a_task_of_ones_own_under_brax_training_stack():
  """The high jump (mjx_hopper.envs.events) under Brax's EpisodeWrapper, AutoResetWrapper and
  EvalWrapper: its own terms are summed per episode, and Brax's limit ends its episodes."""
  from mjx_hopper.envs.events import HighJump
  env = HighJump(episode_steps=300)
  stack = training.EvalWrapper(training.wrap(env, episode_length=12))
  hold = jnp.zeros((N, env.action_size))

  @jax.jit
  def run(keys):
    def one(state, _):
      state = stack.step(state, hold)
      return state, state
    return jax.lax.scan(one, stack.reset(keys), None, length=12)

  last, states = jax.device_get(run(jax.random.split(jax.random.PRNGKey(2), N)))
  assert "height" in states.metrics and "progress" not in states.metrics
  np.testing.assert_array_equal(states.done[-1], 1)          # Brax's 12 steps, not 300
  np.testing.assert_array_equal(states.info["truncation"][-1], 1)
  np.testing.assert_allclose(last.info["eval_metrics"].episode_metrics["height"],
                             states.metrics["height"].sum(0), rtol=1e-5)


def heavier_torso(env, sys, scales):
  """Brax's randomization_fn: the torso's mass times each of `scales` (B,), one model each."""
  torso = env.mj_model.body("torso").id
  mass = jnp.broadcast_to(sys.body_mass, (len(scales),) + sys.body_mass.shape)
  batch = sys.tree_replace({"body_mass": mass.at[:, torso].multiply(scales)})
  in_axes = jax.tree.map(lambda _: None, sys).tree_replace({"body_mass": 0})
  return batch, in_axes


@pytest.mark.slow  # its own programs: a batch of models under Brax's randomisation
def test_domain_randomisation_changes_the_physics(hopper):
  scales = jnp.array([1.0, 0.5, 2.0, 4.0])
  randomise = functools.partial(heavier_torso, hopper, scales=scales)
  brax_stack = training.wrap(hopper, episode_length=1000, randomization_fn=randomise)
  ours = envs.AutoReset(training.DomainRandomizationVmapWrapper(hopper, randomise))
  plain = training.VmapWrapper(hopper)
  model = hopper.mjx_model
  action = jnp.full((N, 3), 0.5)

  def rollout(stack, keys):
    def one(state, _):
      state = stack.step(state, action)
      return state, (state.pipeline_state.qpos, state.done)
    return jax.lax.scan(one, stack.reset(keys), None, length=15)[1]

  @jax.jit
  def run(keys):
    # Our AutoReset splits its key and resets with the second half; the others get that half.
    inner = jax.vmap(lambda k: jax.random.split(k)[1])(keys)
    return rollout(brax_stack, inner), rollout(ours, keys), rollout(plain, inner)

  # One start for every env, so that only the model differs.
  same = jnp.broadcast_to(jax.random.PRNGKey(2), (N, 2))
  (brax_qpos, done), (our_qpos, _), (plain_qpos, _) = jax.device_get(run(same))
  assert not done.any()
  assert hopper.mjx_model is model  # the wrapper put the env's own model back
  # The tolerances: these are separately compiled programs, so XLA may order float sums
  # differently; 15 steps of the same physics stay within 1e-5.
  np.testing.assert_allclose(brax_qpos[:, 0], plain_qpos[:, 0], atol=1e-5)  # torso x 1
  np.testing.assert_allclose(our_qpos, brax_qpos, atol=1e-5)
  moved = np.abs(brax_qpos[-1, 1:] - brax_qpos[-1, :1]).max(axis=-1)
  assert (moved > 1e-2).all(), f"torso mass x{scales[1:]} moved the pose by only {moved}"


def small_run(trainer, **settings):
  """Runs a Brax trainer on our Hopper; returns (params, [(env steps, metrics)] as
  progress_fn got them)."""
  progress = []
  _, params, _ = trainer(
      envs.make("Hopper"), episode_length=EPISODE, num_envs=8, num_eval_envs=EVAL_ENVS,
      num_evals=2, deterministic_eval=True, normalize_observations=True, seed=0,
      progress_fn=lambda step, metrics: progress.append((step, jax.device_get(metrics))),
      **settings)
  return params, progress


def check_progress(progress, env_steps, losses):
  """Two evaluations, before and after `env_steps` of training, with our reward terms; and
  finite training losses."""
  assert [step for step, _ in progress] == [0, env_steps]
  for _, metrics in progress:
    # Each of the EVAL_ENVS episodes ends at step EPISODE, or earlier by a fall, a step that
    # scores alive -1 instead of +1; so the falls are EVAL_ENVS * (length - alive) / 2 on
    # average, and the others ran all EPISODE steps. (With each step counted twice, by the
    # env and by Brax's EpisodeWrapper, episodes would stop at step EPISODE / 2 unfallen.)
    length, alive = metrics["eval/avg_episode_length"], metrics["eval/episode_alive"]
    falls = EVAL_ENVS * (length - alive) / 2
    assert abs(falls - round(falls)) < 1e-3 and 0 <= round(falls) <= EVAL_ENVS, falls
    assert EVAL_ENVS * length >= (EVAL_ENVS - round(falls)) * EPISODE + round(falls)
    assert np.isfinite(metrics["eval/episode_reward"])
    assert {f"eval/episode_{name}" for name in envs.REWARD_TERMS} <= set(metrics)
  for name in losses:
    assert np.isfinite(progress[-1][1][f"training/{name}"]), name


@pytest.mark.slow
def test_brax_ppo_trains_on_our_env(brax_trainers):
  train_ppo = brax_trainers
  # One iteration collects 8 envs x 4 steps x 4 minibatches = 128 env steps; 2 of them.
  params, progress = small_run(
      train_ppo, num_timesteps=256, unroll_length=4, batch_size=8, num_minibatches=4,
      num_updates_per_batch=1, network_factory=functools.partial(
          ppo_networks.make_ppo_networks, policy_hidden_layer_sizes=(16,),
          value_hidden_layer_sizes=(16,)))
  check_progress(progress, 256, ["policy_loss", "v_loss", "entropy_loss"])
  normalizer, policy, value = params
  assert normalizer.mean.shape == (15,)
  assert int(normalizer.count.lo) == 256  # it saw the observation of every env step
  assert policy["params"]["hidden_1"]["kernel"].shape == (16, 6)  # mean and scale of 3
  assert value["params"]["hidden_1"]["kernel"].shape == (16, 1)
