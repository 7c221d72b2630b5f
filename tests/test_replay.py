"""The n-step replay against a plain-Python reference."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_hopper.core import replay

GAMMA = 0.9


def reference_n_step(history, start, n, gamma):
  """The n-step transition from step `start` of one env's list of steps (dicts), walking
  forward and stopping at the step that ended the episode."""
  reward, power = 0.0, 1.0
  for k in range(n):
    step = history[start + k]
    reward += power * step["reward"]
    power *= gamma
    if step["done"] or k == n - 1:
      return {"obs": history[start]["obs"], "action": history[start]["action"],
              "reward": reward, "discount": power * step["discount"],
              "next_obs": step["next_obs"]}


def random_history(rng, length, obs_size=2, action_size=1):
  """Steps of one env: episodes that end by termination (discount 0) or by a time limit."""
  steps = []
  for t in range(length):
    done = rng.random() < 0.25
    terminated = done and rng.random() < 0.5
    steps.append({"obs": rng.normal(size=obs_size), "action": rng.normal(size=action_size),
                  "reward": rng.normal(), "discount": 0.0 if terminated else 1.0,
                  "done": float(done), "next_obs": rng.normal(size=obs_size), "t": t})
  return steps


def as_step(steps):
  return replay.Step(**{k: jnp.asarray(np.array([s[k] for s in steps]), jnp.float32)
                        for k in replay.Step._fields})


@pytest.mark.parametrize("n", [1, 3, 5])
def test_n_step_transition_matches_reference(n):
  rng = np.random.default_rng(n)
  history = random_history(rng, 200)
  starts = range(len(history) - n + 1)
  windows = [as_step(history[s:s + n]) for s in starts]
  window = jax.tree.map(lambda *xs: jnp.stack(xs), *windows)
  got = replay.n_step_transition(window, GAMMA)
  for i, s in enumerate(starts):
    want = reference_n_step(history, s, n, GAMMA)
    for field in replay.Transition._fields:
      np.testing.assert_allclose(getattr(got, field)[i], want[field], rtol=1e-5, atol=1e-6,
                                 err_msg=f"start {s}, {field}")


def test_truncation_bootstraps_and_termination_does_not():
  # Two 3-step windows whose first step ends the episode: by time limit, then by termination.
  base = dict(obs=[0.0], action=[0.0], reward=1.0, next_obs=[7.0])
  window = as_step([dict(base, done=1.0, discount=1.0), dict(base, done=0.0, discount=1.0),
                    dict(base, done=0.0, discount=1.0)])
  truncated = replay.n_step_transition(jax.tree.map(lambda x: x[None], window), GAMMA)
  assert float(truncated.discount[0]) == pytest.approx(GAMMA)   # bootstrap from next_obs
  assert float(truncated.reward[0]) == pytest.approx(1.0)       # later steps not counted
  terminated = replay.n_step_transition(
      jax.tree.map(lambda x: x[None], window._replace(discount=window.discount.at[0].set(0.0))),
      GAMMA)
  assert float(terminated.discount[0]) == 0.0
  # No ending within n steps: gamma^n, and all n rewards.
  running = replay.n_step_transition(
      jax.tree.map(lambda x: x[None], window._replace(done=jnp.zeros(3))), GAMMA)
  assert float(running.discount[0]) == pytest.approx(GAMMA ** 3)
  assert float(running.reward[0]) == pytest.approx(1 + GAMMA + GAMMA ** 2)


def test_sample_draws_valid_n_step_transitions_after_wrapping():
  rng = np.random.default_rng(0)
  num_envs, rows, unroll, n = 3, 12, 4, 3
  histories = [random_history(rng, 40) for _ in range(num_envs)]
  for e, history in enumerate(histories):  # tag obs with (env, time) to find the start
    for step in history:
      step["obs"] = np.array([e, step["t"]], np.float64)
  state = replay.init(rows, num_envs, obs_size=2, action_size=1)
  insert = jax.jit(replay.insert)
  for t0 in range(0, 40, unroll):  # 40 rows into a 12-row ring: the oldest are overwritten
    block = [as_step(h[t0:t0 + unroll]) for h in histories]
    state = insert(state, jax.tree.map(lambda *xs: jnp.stack(xs, 1), *block))
  assert int(state.filled) == rows and int(state.position) == 40 % rows
  batch = jax.jit(replay.sample, static_argnums=(2, 3, 4))(state, jax.random.PRNGKey(1), 2000, n,
                                                          GAMMA)
  starts = set()
  for i in range(2000):
    env, t = (int(v) for v in np.asarray(batch.obs[i]))
    starts.add(t)
    want = reference_n_step(histories[env], t, n, GAMMA)
    for field in ("action", "reward", "discount", "next_obs"):
      np.testing.assert_allclose(getattr(batch, field)[i], want[field], rtol=1e-5, atol=1e-6)
  assert starts == set(range(40 - rows, 40 - n + 1))  # only kept rows with n - 1 rows after


def test_insert_needs_blocks_that_divide_the_ring():
  state = replay.init(10, 2, 1, 1)
  block = replay.Step(*(jnp.zeros((4, 2, 1)),) * 2, *(jnp.zeros((4, 2)),) * 3, jnp.zeros((4, 2, 1)))
  with pytest.raises(ValueError, match=r"replay rows \(10\) must be a multiple of the rows per "
                                       r"insert \(4\)"):
    replay.insert(state, block)
