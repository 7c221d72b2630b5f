"""The compiled trainer and the host loop, on a tiny Hopper run over two CPU devices."""

import csv
import dataclasses
import json
import os

import jax
import numpy as np
import pytest

from mjx_hopper import agents, store
from mjx_hopper.core import evaluator, start, train
from mjx_hopper.faces import cli
from mjx_hopper.process import distributed
from mjx_hopper.run import checkpoints, logger, loop, trainers
from mjx_hopper.settings.plan import resolve

from configs import TINY, tiny_args


@pytest.fixture(scope="module")
def trainer():
  return trainers.build(resolve(TINY))  # the trainer that loop.run(TINY) below reuses


@pytest.fixture(scope="module")
def two_chunks(trainer):
  """Host copies of the (one member's) state after one and two chunks and the second chunk's
  metrics, and the state after two chunks on the devices."""
  first, _ = trainer.train_chunk(trainer.init([0]))
  first_host = member(first)
  second, metrics = trainer.train_chunk(first)  # donates `first`
  return first_host, member(second), member(metrics), second


def member(tree, i=0):
  """Member i's part of a trainer's pytree (every leaf has a leading member axis), on the host."""
  return jax.tree.map(lambda x: x[i], jax.device_get(tree))


def test_counters_and_replay_fill(two_chunks):
  first, second, metrics, _ = two_chunks
  assert int(first.iteration) == 5 and int(second.iteration) == 10
  rows = TINY.train.replay_rows
  assert rows == 16  # 64 transitions / 4 envs
  assert int(second.replay.filled) == min(20, rows)
  assert int(second.replay.position) == 20 % rows
  # Learning starts once 24 transitions (6 rows) are in: iteration 3 of the first chunk.
  assert int(first.updates) == 3 * TINY.train.updates_per_iteration
  assert int(second.updates) == 8 * TINY.train.updates_per_iteration
  assert float(metrics["learning"]) == 1.0
  assert np.isfinite([float(v) for v in metrics.values() if np.ndim(v) == 0]).all()


def test_stored_steps_chain_within_episodes(two_chunks):
  _, state, _, _ = two_chunks
  steps = state.replay.steps
  order = (state.replay.position + np.arange(16)) % 16        # oldest row first
  obs, next_obs = steps.obs[order], steps.next_obs[order]
  done, discount = steps.done[order], steps.discount[order]
  running = done[:-1] == 0
  # Within an episode, the next observation is the next row's observation.
  np.testing.assert_array_equal(next_obs[:-1][running], obs[1:][running])
  # Only an ended episode may have env discount 0 (a termination).
  assert (discount[done == 0] == 1).all()
  assert set(np.unique(discount)) <= {0.0, 1.0}


def test_state_is_sharded_and_params_replicated(two_chunks):
  state = two_chunks[-1]
  assert len(jax.devices()) == 2
  assert state.env.obs.addressable_shards[0].data.shape == (1, 2, 15)
  assert state.replay.steps.obs.addressable_shards[0].data.shape == (1, 16, 2, 15)
  kernel = jax.tree.leaves(state.agent.policy)[0]
  a, b = (np.asarray(s.data) for s in kernel.addressable_shards)
  np.testing.assert_array_equal(a, b)  # data-parallel learner: identical copies


def test_same_seed_same_run(trainer, two_chunks):
  first, _, _, _ = two_chunks
  again, _ = trainer.train_chunk(trainer.init([0]))
  jax.tree.map(np.testing.assert_array_equal, member(again), first)


def test_evaluate_runs_whole_episodes(trainer):
  state = trainer.init([0])
  result = jax.device_get(trainer.evaluate(state.agent, jax.random.PRNGKey(1)[None]))
  assert result["return"].shape == (1, TINY.eval_episodes)
  assert ((result["length"] >= 1) & (result["length"] <= 30)).all()


@pytest.mark.parametrize("change, message", [
    ({"replay_size": 4}, r"replay_size \(4\) must be at least batch_size \(8\)"),
    ({"replay_ratio": 1.5}, "must be a whole number of updates >= 1, got 1.5 \\* 4 \\* 2 / 8"),
    ({"num_envs": 3, "replay_ratio": 8 / 6}, r"num_envs \(3\) must divide evenly over the 2"),
    ({"unroll_length": 0}, "unroll_length must be an integer >= 1, got 0"),
])
def test_bad_train_config(change, message):
  with pytest.raises(ValueError, match=message):
    dataclasses.replace(TINY.train, **change).check(num_devices=2)


def test_bad_run_config():
  with pytest.raises(ValueError, match=r"unknown env 'Hoppr'; valid envs are \['Ant'"):
    loop.RunConfig(env="Hoppr")
  with pytest.raises(ValueError, match=r"unknown agent 'sac'; valid agents are \['d4pg'"):
    loop.RunConfig(agent="sac")
  with pytest.raises(ValueError, match="n_step must be an integer >= 1, got 0"):
    loop.RunConfig(agent_overrides={"n_step": 0})
  with pytest.raises(ValueError, match="eval_on must be one of auto, host, train, got 'cpu'"):
    loop.RunConfig(eval_on="cpu")


def test_where_evaluations_run():
  """"auto" evaluates on the host's CPU a single run that trains on an accelerator."""
  assert not TINY.evaluates_on_host("cpu", 1)  # it trains on the CPU
  assert dataclasses.replace(TINY, eval_on="host").evaluates_on_host("cpu", 1)
  assert TINY.evaluates_on_host("gpu", 1)
  assert not TINY.evaluates_on_host("gpu", 2)  # a sweep (or PBT)
  assert not dataclasses.replace(TINY, eval_on="train").evaluates_on_host("gpu", 1)


def test_run_logs_checkpoints_and_resumes(tmp_path, capsys):
  cfg = dataclasses.replace(TINY, out_dir=str(tmp_path / "run"))
  result = loop.run(cfg, progress=False)
  assert result.trainer.env_steps(result.state) >= 80
  with open(tmp_path / "run" / "log.csv") as f:
    rows = list(csv.DictReader(f))
  assert {"env_steps", "steps_per_s", "episode_return", "critic_loss", "eval_return"} <= set(
      rows[0])
  assert [r["kind"] for r in rows].count("eval") == 2  # at 40 and at 80 env steps
  steps = sorted(int(p) for p in os.listdir(tmp_path / "run" / "checkpoints") if p.isdigit())
  assert steps == [train.iterations(result.state)]
  assert json.load(open(tmp_path / "run" / "config.json"))["agent_config"]["n_step"] == 3
  curves_png = tmp_path / "run" / "curves.png"
  assert curves_png.stat().st_size > 10_000  # a single run draws its curve, as a sweep does
  curves_png.unlink()
  # A longer run from the same folder continues from the checkpoint, and draws it again.
  longer = loop.run(dataclasses.replace(cfg, total_env_steps=160), progress=False)
  out = capsys.readouterr().out
  assert "resumed from" in out and f"learning curves: {curves_png}" in out
  assert curves_png.stat().st_size > 10_000
  assert "nan" not in out  # no return is shown before it is known
  assert train.iterations(longer.state) == 2 * train.iterations(result.state)
  # The agent of the best evaluation so far is kept beside the latest: it scores that
  # evaluation again (the same program and key), and is what a policy loads by default.
  evals = [r for r in longer.history if r["kind"] == "eval"]
  best = max(evals, key=lambda r: float(r["eval_return"]))
  assert best is not evals[-1]  # (so that best and latest differ)
  assert longer.best_return[0] == pytest.approx(float(best["eval_return"]), rel=1e-6)
  key = jax.random.fold_in(jax.random.PRNGKey(cfg.seed), int(best["env_steps"]))
  again = jax.device_get(longer.trainer.evaluate(longer.best, key[None]))
  assert np.mean(again["return"][0]) == pytest.approx(float(best["eval_return"]), rel=1e-5)
  directory = str(tmp_path / "run" / "checkpoints")
  for which, want in (("best", longer.best), ("latest", longer.state.agent)):
    _, agent, trainer = checkpoints.load_policy(directory, which=which)
    jax.tree.map(np.testing.assert_array_equal, agent, member(want))
    assert trainer is longer.trainer  # conftest's shared builds cover checkpoints.load_policy too
  assert f"return {longer.best_return[0]:.1f} at {int(best['env_steps']):,} env steps" in (
      capsys.readouterr().out)
  # Another config is refused, naming what differs, before a trainer is built for it, and the
  # checkpoint is left alone.
  with pytest.MonkeyPatch.context() as patch, pytest.raises(
      ValueError, match="from another config .*agent_config"):
    patch.setattr(trainers, "build", lambda *_: pytest.fail("a trainer was built"))
    loop.run(dataclasses.replace(cfg, agent_overrides={**cfg.agent_overrides, "n_step": 2}),
             progress=False)
  assert max(int(p) for p in os.listdir(tmp_path / "run" / "checkpoints") if p.isdigit()) == (
      train.iterations(longer.state))
  # The CLI's eval loads just the policy and writes a video.
  video = tmp_path / "policy.mp4"
  cli.main(["--cpu-devices", "2", "eval", "--checkpoint", str(tmp_path / "run" / "checkpoints"),
            "--episodes", "2", "--video", str(video)])
  out = capsys.readouterr().out
  assert "over 2 episodes" in out and "the policy of its best evaluation" in out
  assert video.stat().st_size > 1000


# D4PG's CLI run is test_checkpoint.py's bit-exact test (the same settings, in fresh processes).
# Each agent's tiny run, as the notebook's short mode trains it (tests/configs.py).
# Slow: MPO's and DMPO's, trainers of their own (their learners are test_mpo.py's; evaluations
# on the host are test_evaluations_on_the_host_run_beside_training's).
@pytest.mark.parametrize("agent, extra", [
    ("ddpg", []),
    pytest.param("mpo", ["--eval-on", "host"], marks=pytest.mark.slow),
    pytest.param("dmpo", [], marks=pytest.mark.slow),
])
def test_every_agent_trains_from_the_same_cli(tmp_path, capsys, agent, extra):
  cli.main([*tiny_args(agent), *extra, "--total-env-steps", "80", "--out-dir", str(tmp_path)])
  # The terminal lines are short: the agent's learner figures, not every logged field.
  last = [line for line in capsys.readouterr().out.splitlines() if line.startswith("[train]")][-1]
  for _, text in agents.learner_fields(agent):
    assert "| " + text.format("") in last, text
  assert "q_min" not in last and "nan" not in last
  with open(tmp_path / "log.csv") as f:
    rows = list(csv.DictReader(f))
  train_rows = [r for r in rows if r["kind"] == "train"]
  assert int(train_rows[-1]["updates"]) == 8 * TINY.train.updates_per_iteration
  assert [r["kind"] for r in rows].count("eval") == 2
  names = {"critic_loss", "q_mean", "policy_grad_norm"}
  if agent in ("mpo", "dmpo"):
    names |= {"temperature", "alpha_mean", "alpha_stddev", "kl_q_rel", "kl_mean_rel",
              "policy_std"}
  for name in names:
    assert np.isfinite(float(train_rows[-1][name])), name
  saved = json.load(open(tmp_path / "config.json"))
  assert saved["agent"] == agent
  assert saved["eval_on"] == ("host" if "--eval-on" in extra else "auto")


def test_a_run_that_diverges_stops_and_keeps_its_last_finite_checkpoint(tmp_path, monkeypatch,
                                                                        capsys):
  """The third chunk's critic loss goes NaN: the run stops there, says so, and never saves
  that state; the checkpoint of the chunk before stays the newest, and resumes."""
  chunk, calls = loop.Chunk.__call__, []

  def poisoned(self, state):
    state, ran, before = chunk(self, state)
    calls.append(state)
    if len(calls) == 3:
      ran = ran._replace(metrics={**ran.metrics, "critic_loss": np.full_like(
          ran.metrics["critic_loss"], np.nan)})
    return state, ran, before
  monkeypatch.setattr(loop.Chunk, "__call__", poisoned)
  cfg = dataclasses.replace(TINY, out_dir=str(tmp_path), total_env_steps=400,
                            checkpoint_minutes=0.0)
  result = loop.run(cfg, progress=False)
  out = capsys.readouterr().out
  assert "[diverged] at 120 env steps: critic_loss not finite" in out
  assert f"the last finite checkpoint is step 10 in {tmp_path / 'checkpoints'}" in out
  assert "diverged: 120 env steps" in out and len(calls) == 3
  assert store.manager(str(tmp_path / "checkpoints")).all_steps() == [5, 10]
  last = [r for r in result.history if r["kind"] == "train"][-1]
  assert np.isnan(last["critic_loss"])  # the diverged chunk's row is logged
  # The evaluations due at 40 and 80 env steps ran, however long their compile took.
  assert [int(r["env_steps"]) for r in result.history if r["kind"] == "eval"] == [40, 80]
  monkeypatch.setattr(loop.Chunk, "__call__", chunk)
  resumed = loop.resume(str(tmp_path / "checkpoints"), progress=False, total_env_steps=160)
  assert train.iterations(resumed.state) == 20


def test_evaluations_due_while_the_evaluation_compiles_are_kept_and_done_later(tmp_path,
                                                                              monkeypatch):
  """An evaluation due before its program is compiled does not hold up training: the agents of
  that moment are kept and evaluated once it is, with the same results as evaluated on time."""
  cfg = dataclasses.replace(TINY, total_env_steps=160)  # an evaluation due after every chunk
  begin = start.start

  class Compiling:
    """The evaluation's future, reported unfinished for the first `late` chunks, and finished
    (waiting for it) after them."""

    def __init__(self, future, late):
      self.future, self.late = future, late

    def done(self):
      self.late -= 1
      return self.late < 0 and self.future.result() is not None

    def result(self):
      return self.future.result()

  def run(late):
    def slow_compile(*args):
      started = begin(*args)
      return started._replace(evaluation=Compiling(started.evaluation, late))
    monkeypatch.setattr(start, "start", slow_compile)
    return loop.run(dataclasses.replace(cfg, out_dir=str(tmp_path / str(late))), progress=False)
  on_time, deferred = run(0), run(2)
  order = [(r["kind"], int(r["env_steps"])) for r in deferred.history]
  assert order[:5] == [("train", 40), ("train", 80), ("train", 120), ("eval", 40), ("eval", 80)]
  evals = {which: [(int(r["env_steps"]), float(r["eval_return"]))
                   for r in result.history if r["kind"] == "eval"]
           for which, result in (("on time", on_time), ("late", deferred))}
  assert [s for s, _ in evals["late"]] == [s for s, _ in evals["on time"]] == [40, 80, 120, 160]
  np.testing.assert_allclose([r for _, r in evals["late"]], [r for _, r in evals["on time"]],
                             rtol=1e-5)
  assert deferred.best_return[0] == pytest.approx(on_time.best_return[0], rel=1e-5)


def _evaluations_compiled_first_and_never_finished(monkeypatch):
  """The evaluation compiled before training starts, and every poll of a host evaluation's
  result saying unfinished (after asking JAX), so that only waiting logs one."""
  begin, finished = start.start, evaluator._finished

  def compiled_first(*args):
    started = begin(*args)
    started.evaluation.result()
    return started
  monkeypatch.setattr(start, "start", compiled_first)
  monkeypatch.setattr(evaluator, "_finished", lambda started: finished(started) and False)


def test_evaluations_on_the_host_run_beside_training(tmp_path, monkeypatch):
  """With eval_on="host", training goes on while the host evaluates: an evaluation is logged once
  finished (here never), or when more than MAX_PENDING wait, oldest first, and the last waits
  for the rest. The returns are those of the run that evaluates on its training's devices (both
  on the two CPU devices here), to the tolerance of another program (30 steps of contacts
  amplify rounding); the best agent is the same, and the trainer's own evaluation takes it."""
  assert evaluator.MAX_PENDING == 3
  cfg = dataclasses.replace(TINY, total_env_steps=200)  # an evaluation due after every chunk
  _evaluations_compiled_first_and_never_finished(monkeypatch)

  def run(eval_on):
    return loop.run(dataclasses.replace(cfg, eval_on=eval_on, out_dir=str(tmp_path / eval_on)),
                    progress=False)
  on_devices, on_host = run("train"), run("host")
  order = [(r["kind"], int(r["env_steps"])) for r in on_host.history]
  assert order == [("train", 40), ("train", 80), ("train", 120), ("train", 160), ("eval", 40),
                   ("train", 200), ("eval", 80), ("eval", 120), ("eval", 160), ("eval", 200)]
  evals = {which: [(int(r["env_steps"]), float(r["eval_return"]))
                   for r in result.history if r["kind"] == "eval"]
           for which, result in (("devices", on_devices), ("host", on_host))}
  assert [s for s, _ in evals["host"]] == [s for s, _ in evals["devices"]] == [40, 80, 120, 160,
                                                                              200]
  np.testing.assert_allclose([r for _, r in evals["host"]], [r for _, r in evals["devices"]],
                             rtol=1e-3)
  assert on_host.best_return[0] == pytest.approx(on_devices.best_return[0], rel=1e-3)
  for a, b in zip(jax.tree.leaves(on_host.best), jax.tree.leaves(on_devices.best)):
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)
  again = on_host.trainer.evaluate(on_host.best, jax.random.PRNGKey(0)[None])
  assert np.isfinite(np.asarray(again["return"])).all()


def test_host_evaluations_pending_at_a_divergence_or_a_checkpoint_still_count(tmp_path,
                                                                             monkeypatch):
  """Evaluations still on the host when the run diverges are logged, and their agents (taken
  before it diverged) can be its best; a checkpoint waits for those due before it, so that
  its record holds them."""
  chunk, calls = loop.Chunk.__call__, []

  def poisoned(self, state):  # the third chunk's critic loss goes NaN
    state, ran, before = chunk(self, state)
    calls.append(1)
    if len(calls) == 3:
      ran = ran._replace(metrics={**ran.metrics, "critic_loss": np.full_like(
          ran.metrics["critic_loss"], np.nan)})
    return state, ran, before
  _evaluations_compiled_first_and_never_finished(monkeypatch)
  monkeypatch.setattr(loop.Chunk, "__call__", poisoned)
  cfg = dataclasses.replace(TINY, eval_on="host", out_dir=str(tmp_path / "diverges"),
                            total_env_steps=400)
  result = loop.run(cfg, progress=False)
  evals = [(int(r["env_steps"]), r["eval_return"]) for r in result.history if r["kind"] == "eval"]
  assert [s for s, _ in evals] == [40, 80] and len(calls) == 3
  assert result.best_return[0] == pytest.approx(max(r for _, r in evals))
  calls.clear()
  monkeypatch.setattr(loop.Chunk, "__call__", chunk)
  saved = loop.run(dataclasses.replace(cfg, out_dir=str(tmp_path / "saves"),
                                       total_env_steps=80, checkpoint_minutes=0.0),
                   progress=False)
  first = next(r for r in saved.history if r["kind"] == "eval")
  assert saved.history.index(first) == 1  # logged before the first checkpoint, not after 80
  record = store.read_config(store.manager(str(tmp_path / "saves" / "checkpoints")),
                                  5)["record"]
  assert record["best_return"] == [pytest.approx(first["eval_return"])]
  assert record["best_env_steps"] == [40]


def test_progress_fn_sees_every_row_and_its_false_ends_the_run_cleanly(tmp_path):
  """progress_fn gets what log.csv gets, after each chunk and each evaluation; returning False
  ends the run as max_minutes does: that chunk is evaluated, saved and logged."""
  calls = []

  def progress_fn(env_steps, metrics):
    calls.append((env_steps, metrics["kind"], metrics.get("eval_return")))
    return not (metrics["kind"] == "train" and env_steps >= 80)
  cfg = dataclasses.replace(TINY, total_env_steps=400, eval_every=80,
                            out_dir=str(tmp_path))
  result = loop.run(cfg, progress=False, progress_fn=progress_fn)
  assert [(s, k) for s, k, _ in calls] == [(40, "train"), (80, "train"), (80, "eval")]
  with open(tmp_path / "log.csv") as f:
    rows = list(csv.DictReader(f))
  assert [(int(r["env_steps"]), r["kind"]) for r in rows] == [(s, k) for s, k, _ in calls]
  assert calls[-1][2] == pytest.approx(float(rows[-1]["eval_return"]))
  assert store.manager(str(tmp_path / "checkpoints")).all_steps() == [
      train.iterations(result.state)] == [10]
  # A deadline that has passed before the first chunk (here, at once) ends the run in the same
  # way after one chunk: a run always trains one, however long its programs took to compile.
  resumed = loop.run(dataclasses.replace(cfg, max_minutes=1e-9), progress=False)
  assert [(int(r["env_steps"]), r["kind"]) for r in resumed.history] == [
      *((s, k) for s, k, _ in calls), (120, "train"), (120, "eval")]
  assert store.manager(str(tmp_path / "checkpoints")).all_steps() == [10, 15]


class Broken(Exception):
  """A bug in the user's code."""


@pytest.mark.parametrize("where", ["progress_fn", "the logger"])
def test_an_exception_from_user_code_saves_first_and_the_run_resumes_there(tmp_path, monkeypatch,
                                                                           capsys, where):
  """An exception from progress_fn, or from a logger's sink (W&B losing its connection, say),
  ends the run as Ctrl-C does: its chunk is saved, then the exception is raised."""
  progress_fn = None
  if where == "progress_fn":
    def progress_fn(env_steps, metrics):
      if env_steps >= 80:
        raise Broken("the user's callback")
  else:
    write_csv = logger.Logger._write_csv

    def sink(self, row):
      if row["env_steps"] >= 80:
        raise Broken("a logger's sink")
      write_csv(self, row)
    monkeypatch.setattr(logger.Logger, "_write_csv", sink)
  cfg = dataclasses.replace(TINY, total_env_steps=400, out_dir=str(tmp_path))
  with pytest.raises(Broken):
    loop.run(cfg, progress=False, progress_fn=progress_fn)
  assert f"stopped by {where}'s Broken: 80 env steps in" in capsys.readouterr().out
  directory = str(tmp_path / "checkpoints")
  assert store.manager(directory).all_steps() == [10]  # (no periodic save was due)
  monkeypatch.undo()
  resumed = loop.resume(directory, progress=False, total_env_steps=120)
  assert f"resumed from {directory}, step 10" in capsys.readouterr().out
  assert train.iterations(resumed.state) == 15


def test_an_error_in_the_chunk_names_the_checkpoint_that_resumes(tmp_path, monkeypatch, capsys):
  """A chunk that fails (a reward's host callback, say) takes its state with it (the chunk
  takes its input's memory); the run waits for the save in flight and names what is kept."""
  chunk, calls = loop.Chunk.__call__, []

  def failing(self, state):
    calls.append(None)
    if len(calls) == 3:
      raise Broken("a reward's host callback")
    return chunk(self, state)
  monkeypatch.setattr(loop.Chunk, "__call__", failing)
  cfg = dataclasses.replace(TINY, total_env_steps=400, out_dir=str(tmp_path),
                            checkpoint_minutes=0.0)
  with pytest.raises(Broken):
    loop.run(cfg, progress=False)
  directory = tmp_path / "checkpoints"
  assert (f"the run stopped at an error: {directory} holds its checkpoint step 10, which "
          "resumes it") in capsys.readouterr().out
  assert sorted(os.listdir(directory)) == ["10", "5", "manifests"]


def test_a_signal_to_another_process_stops_this_one_after_its_chunk_saved(tmp_path, monkeypatch,
                                                                         capsys):
  """Where another process of a run over processes was signalled (the flag the processes agree
  on after each chunk), this one stops after its chunk too, saves, and says why."""
  agree = distributed.agree

  def signalled_elsewhere(phase, *flags):  # (last, signalled, saving, compiling) after a chunk
    agreed = agree(phase, *flags)
    return (agreed[0], True, *agreed[2:]) if phase == "after the chunk" else agreed
  monkeypatch.setattr(distributed, "agree", signalled_elsewhere)
  cfg = dataclasses.replace(TINY, total_env_steps=160, out_dir=str(tmp_path))
  result = loop.run(cfg, progress=False)
  assert result.trainer.env_steps(result.state) == 40
  assert store.manager(str(tmp_path / "checkpoints")).latest_step() == 5
  assert "stopped by a signal to another process: 40 env steps" in capsys.readouterr().out
