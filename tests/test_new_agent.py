"""A new agent is one file and one line: an agent defined here, outside agents/, registered
through `agents.register`, trains with `loop.run` as a sweep, checkpoints, resumes, is
evaluated, exported and loaded, and its learner metrics reach log.csv. No file of the package
names it."""

import csv
import dataclasses
import sys
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from mjx_hopper import agents
from mjx_hopper.agents import networks
from mjx_hopper.agents.base import Agent, CommonConfig, hparams
import configs
from mjx_hopper.faces import cli, export, notebook
from mjx_hopper.run import loop
from mjx_hopper.run.logger import Logger


@dataclasses.dataclass(frozen=True)
class LinearConfig(CommonConfig):
  """A linear policy fitted to a linear critic's greedy step: small, but it learns."""
  DYNAMIC = CommonConfig.DYNAMIC + ("sigma",)
  sigma: float = 0.3


class LinearState(NamedTuple):
  policy: jax.Array   # (O, A)
  critic: jax.Array   # (O + A,)
  opt: optax.OptState
  hparams: dict


def make_linear(obs_size: int, action_size: int, cfg: LinearConfig) -> Agent:
  opt = optax.sgd(cfg.learning_rate)

  def init(key, hp=None):
    policy = 0.01 * jax.random.normal(key, (obs_size, action_size))
    critic = jnp.zeros(obs_size + action_size)
    return LinearState(policy, critic, opt.init((policy, critic)),
                       hparams(cfg) if hp is None else hp)

  def policy(state, obs):
    return jnp.tanh(obs @ state.policy)

  def act(state, obs, key):
    noise = state.hparams["sigma"] * jax.random.normal(key, obs.shape[:-1] + (action_size,))
    return jnp.clip(policy(state, obs) + noise, -1.0, 1.0)

  def update(state, batch, key, axis_name=None):
    def loss(params):
      w_policy, w_critic = params
      q = jnp.concatenate([batch.obs, batch.action], -1) @ w_critic
      target = batch.reward + batch.discount * jax.lax.stop_gradient(
          jnp.concatenate([batch.next_obs, jnp.tanh(batch.next_obs @ w_policy)], -1) @ w_critic)
      greedy = jnp.concatenate([batch.obs, jnp.tanh(batch.obs @ w_policy)], -1)
      return jnp.mean((q - target) ** 2) - jnp.mean(greedy @ jax.lax.stop_gradient(w_critic))
    value, grads = jax.value_and_grad(loss)((state.policy, state.critic))
    if axis_name is not None:
      grads = jax.lax.pmean(grads, axis_name)
    updates, opt_state = opt.update(grads, state.opt)
    policy_w, critic_w = optax.apply_updates((state.policy, state.critic), updates)
    return state._replace(policy=policy_w, critic=critic_w, opt=opt_state), {"linear_loss": value}

  return Agent(init, act, policy, update, cfg.n_step, hparams(cfg))


def linear_policy_layers(policy, cfg):
  """The policy tanh(obs @ policy) as one exported layer, then tanh."""
  bias = np.zeros(policy.shape[1], np.float32)
  return [networks.exported_dense({"kernel": policy, "bias": bias}, "float32", False, "none")
          ], "tanh"


DEFAULTS = {"cpu": LinearConfig(learning_rate=1e-3), "gpu": LinearConfig(learning_rate=1e-3)}


@pytest.fixture(scope="module")
def linear():
  agents.register("linear", make_linear, DEFAULTS, (("linear_loss", "linear loss {}"),),
                  tiny={"n_step": 2}, exported_policy=linear_policy_layers)
  yield "linear"
  agents._AGENTS.pop("linear")


def test_a_registered_agent_trains_sweeps_checkpoints_and_resumes(linear, tmp_path, capsys):
  # Four members, by replay ratio and n-step window: the trainer's own dynamic settings, which
  # every agent's sweep takes (each member's update count and window are its own data).
  cfg = dataclasses.replace(
      notebook.tiny(loop.RunConfig(env="Hopper", agent=linear)),
      grid={"replay_ratio": (1.0, 2.0), "n_step": (1, 3)}, log_every=0.0, out_dir=str(tmp_path))
  # The agent's own dynamic setting is sweepable as the built-in agents' are.
  assert len(dataclasses.replace(cfg, grid={"sigma": (0.2, 0.4)}).member_settings()) == 2
  result = loop.run(cfg, progress=False)
  assert result.trainer.agent.n_step == 3  # the replay reads the longest window
  assert result.best_return.shape == (4,)
  # Learning starts at iteration 3 of the first chunk's 5 (24 transitions, 8 an iteration):
  # 3 + 5 iterations of 1 or 2 updates each.
  members = cfg.member_settings()
  assert np.asarray(result.state.updates).tolist() == [8 * int(m["replay_ratio"])
                                                       for m in members]
  assert np.asarray(result.state.agent.hparams["n_step"]).tolist() == [m["n_step"]
                                                                       for m in members]
  with open(tmp_path / "log.csv") as f:
    rows = list(csv.DictReader(f))
  trained = [r for r in rows if r["kind"] == "train"]
  assert len({r["member"] for r in trained}) == 4
  assert all(r["linear_loss"] not in ("", "nan") for r in trained)
  assert [r["kind"] for r in rows].count("eval") == 8  # 4 members at 40 and 80 env steps
  resumed = loop.resume(str(tmp_path / "checkpoints"), progress=False, total_env_steps=120)
  assert "resumed from" in capsys.readouterr().out
  assert resumed.history[-1]["env_steps"] == 120
  # Exported from its checkpoint, it acts with NumPy as its own policy does.
  path = export.export_checkpoint(str(tmp_path / "checkpoints"), str(tmp_path / "policy.npz"),
                                  member=2)
  policy, state = export.load(path), resumed.policy("best", member=2)
  obs = np.random.default_rng(0).normal(size=(4, policy.observation_size)).astype(np.float32)
  assert policy.meta["agent"] == linear
  np.testing.assert_allclose(policy(obs), np.tanh(obs @ np.asarray(state.policy)), rtol=1e-6)


def test_an_agent_in_a_module_of_ones_own_sweeps_evaluates_and_exports_from_the_cli(
    tmp_path, monkeypatch, capsys):
  # The user's module registers it when imported: `--agent my_agents:mine` finds it there, in
  # this process and in any other (a resume, eval or export reads the same name). The sweep is
  # the one above, on the command line: its programs load from the compile cache.
  (tmp_path / "my_agents.py").write_text(
      "from mjx_hopper import agents\n"
      "import test_new_agent as here  # this file's agent\n"
      "agents.register('mine', here.make_linear, here.DEFAULTS, tiny={'n_step': 2},\n"
      "                exported_policy=here.linear_policy_layers)\n")
  monkeypatch.syspath_prepend(str(tmp_path))
  run = str(tmp_path / "run")
  try:
    cli.main([*configs.args_of(configs.tiny("my_agents:mine"), "sweep"), "--set",
              "replay_ratio=1.0,2.0", "--set", "n_step=1,3", "--total-env-steps", "80",
              "--out-dir", run])
    assert agents.config("my_agents:mine") == agents.config("mine") == DEFAULTS["cpu"]
    cli.main(["--cpu-devices", "2", "eval", "--checkpoint", f"{run}/checkpoints", "--member",
              "2", "--episodes", "2", "--video", f"{tmp_path}/v.mp4"])
    cli.main(["export", "--checkpoint", f"{run}/checkpoints", "--member", "2", "--out",
              f"{tmp_path}/p.npz"])
  finally:
    agents._AGENTS.pop("mine", None)
    sys.modules.pop("my_agents", None)
  out = capsys.readouterr().out
  assert "4 members" in out and "over 2 episodes" in out, out
  assert export.load(f"{tmp_path}/p.npz").meta["agent"] == "my_agents:mine"
  assert (tmp_path / "v.mp4").stat().st_size > 0
  with pytest.raises(ValueError, match="module 'test_new_agent' registers no agent 'circle'"):
    agents.config("test_new_agent:circle")
  with pytest.raises(ValueError, match="cannot import the agent 'no_such_module:linear'"):
    agents.config("no_such_module:linear")


def test_the_terminal_line_shows_its_learner_metrics(linear):
  # A single run's logger takes the agent's learner fields (run/opening.py, as for each
  # built-in agent: test_train.test_every_agent_trains_from_the_same_cli).
  lines = []
  logger = Logger(None, log_every=0.0, print_fn=lines.append,
                  learner_fields=agents.learner_fields(linear))
  logger.write({"kind": "train", "env_steps": 80, "steps_per_s": 100.0, "linear_loss": 0.25})
  assert lines[-1].endswith("| linear loss 0.25")


def test_an_agent_without_an_exported_policy_trains_but_is_not_exported():
  agents.register("unexported", make_linear, DEFAULTS)
  try:
    assert agents.config("unexported") == DEFAULTS["cpu"]  # no "acme" defaults: "cpu" are its own
    state = agents.make("unexported", 3, 2).init(jax.random.PRNGKey(0))
    with pytest.raises(ValueError, match="cannot export agent 'unexported': it was registered "
                                         "without an exported_policy"):
      export.policy_of("unexported", DEFAULTS["cpu"], state.policy, 3, 2)
  finally:
    agents._AGENTS.pop("unexported")


def test_an_agent_without_its_defaults_is_refused():
  with pytest.raises(ValueError, match=r"must declare the defaults \['cpu', 'gpu'\]; it lacks "
                                       r"\['gpu'\]"):
    agents.register("half", make_linear, {"cpu": LinearConfig()})
  assert "half" not in agents.list_agents()
