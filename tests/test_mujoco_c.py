"""MuJoCo C as a run's physics (`physics="c"`): it steps as MJX does, a run trains on it and
records it, and what it cannot do is refused. Its fidelity against PyBullet is test_observation's
and test_episodes' (each robot, both engines)."""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import make_env, oracle
from configs import TINY
from mjx_hopper import envs
from mjx_hopper.core import train
from mjx_hopper.run import checkpoints, loop
from mjx_hopper.settings.config import RunConfig


def test_c_steps_as_mjx_does_from_the_same_states():
  """From Bullet's 10 random Hopper states, batched: the same reset poses, and after one control
  step observations within float32 and solver differences (MuJoCo C computes in float64)."""
  bullet = oracle("Hopper")
  qpos, qvel = bullet["random_qpos"], bullet["random_qvel"]
  actions = jax.random.uniform(jax.random.PRNGKey(0), (len(qpos), 3), minval=-1.0, maxval=1.0)
  out = {}
  for physics in ("mjx", "c"):
    env = make_env("Hopper", physics)
    start = jax.jit(jax.vmap(env.init_state))(qpos, qvel)
    out[physics] = jax.device_get((start, jax.jit(jax.vmap(env.step))(start, actions)))
  (start_m, step_m), (start_c, step_c) = out["mjx"], out["c"]
  np.testing.assert_allclose(start_c.obs, start_m.obs, atol=1e-5)
  np.testing.assert_allclose(step_c.obs, step_m.obs, atol=5e-3)
  np.testing.assert_allclose(step_c.pipeline_state.qpos, step_m.pipeline_state.qpos, atol=1e-3)
  assert step_c.obs.dtype == jnp.float32 and step_c.pipeline_state.qpos.dtype == jnp.float32


def test_a_state_that_is_not_finite_ends_its_episode_on_either_engine():
  """MuJoCo C does not reset it to the model's start (its warning handler's default)."""
  for physics in ("mjx", "c"):
    env = make_env("Hopper", physics)
    state = jax.jit(env.reset)(jax.random.PRNGKey(0))
    data = state.pipeline_state
    bad = state.replace(pipeline_state=data.replace(qvel=data.qvel.at[0].set(jnp.nan)))
    out = jax.device_get(jax.jit(env.step)(bad, jnp.zeros(3)))
    assert out.done == 1 and out.reward == 0.0, physics
    assert not np.isfinite(out.pipeline_state.qpos).all(), physics


def test_physics_is_checked_and_is_no_task_setting():
  with pytest.raises(ValueError, match=r"physics must be one of \['mjx', 'c'\], got 'warp'"):
    envs.Hopper(physics="warp")
  with pytest.raises(ValueError, match="physics must be one of mjx, c, got 'warp'"):
    RunConfig(physics="warp")
  env = envs.Hopper(physics="c")
  assert envs.settings_of(env) == {"episode_steps": 1000}  # the same task, stepped otherwise
  with pytest.raises(ValueError, match="built with physics='c', and the run's physics is 'mjx'"):
    RunConfig(env=env)
  assert RunConfig(env=env, physics="c").make_env().physics == "c"

  class Fixed(envs.Hopper):
    def __init__(self, episode_steps: int = 1000):
      super().__init__(episode_steps)
  assert envs.make(Fixed).physics == "mjx"
  with pytest.raises(ValueError, match="Fixed takes no physics setting: its __init__ must pass"):
    envs.make(Fixed, physics="c")
  # Brax's domain randomisation steps each env with a model of its own, which C cannot follow.
  env.sys = env.sys.replace(opt=env.sys.opt.replace(timestep=0.001))
  with pytest.raises(ValueError, match="swaps env.sys .* needs physics='mjx'"):
    jax.eval_shape(env.step, jax.eval_shape(env.reset, jax.random.PRNGKey(0)), jnp.zeros(3))


def test_a_run_trains_on_c_physics_records_it_and_resumes_on_either(tmp_path, capsys,
                                                                    monkeypatch):
  cfg = dataclasses.replace(TINY, physics="c", out_dir=str(tmp_path / "run"))
  result = loop.run(cfg, progress=False)
  rows = [r for r in result.history if r["kind"] == "eval"]
  assert len(rows) == 2 and all(np.isfinite(float(r["eval_return"])) for r in rows)
  assert result.trainer.env.physics == "c"
  assert " envs in MuJoCo C on " in capsys.readouterr().out  # the run's first line
  saved = json.load(open(tmp_path / "run" / "config.json"))
  assert (saved["physics"], saved["env_settings"]) == ("c", {})
  del saved["physics"]  # as saved before the setting: MJX
  assert RunConfig.from_json(saved).physics == "mjx"
  # Where JAX runs on an accelerator, C's checkpoint reads on MJX, saying so.
  with monkeypatch.context() as patch:
    patch.setattr(checkpoints, "_platform", lambda: "gpu")
    lines = []
    read, _, trainer = checkpoints.load_policy(str(tmp_path / "run" / "checkpoints"),
                                               print_fn=lines.append)
  assert (read.physics, trainer.env.physics) == ("mjx", "mjx")
  assert lines[0] == ("the checkpoint trained on MuJoCo C's physics, which runs on the CPU "
                      "alone: it runs on MJX's here (gpu)")
  # The engine is not the task: a run goes on in MJX from C's checkpoint, as on another device.
  longer = loop.run(dataclasses.replace(cfg, physics="mjx", total_env_steps=160), progress=False)
  assert "resumed from" in capsys.readouterr().out
  assert longer.trainer.env.physics == "mjx"
  assert train.iterations(longer.state) == 2 * train.iterations(result.state)
