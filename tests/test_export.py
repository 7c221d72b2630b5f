"""Exported policies: the NumPy file acts as the JAX policy does, for every agent and in both
precisions; it loads without JAX; it evaluates and films from its own task; and bad input is
refused in one line, with nothing written."""

import dataclasses
import json
import os
import pickle
import subprocess
import sys

import jax
import numpy as np
import pytest

import mjx_hopper
from mjx_hopper import agents, store
from mjx_hopper.faces import cli, export
from mjx_hopper.process import runlock
from mjx_hopper.run import checkpoints, loop
from checkpoint_worker import CONFIG, state as fake_state
from configs import TINY

O, A = 15, 3
AGENTS = [("d4pg", {}), ("ddpg", {}), ("mpo", {}), ("mpo", {"action_bounds": "squash"}),
          ("dmpo", {})]


def trained_like(name, dtype, **overrides):
  """(config, agent, state) of a fresh agent whose biases and LayerNorm parameters are made
  random too (a fresh agent's are zeros and ones)."""
  cfg = agents.config(name, "cpu", compute_dtype=dtype, policy_layers=(64, 64), **overrides)
  agent = agents.make(name, O, A, cfg)
  state = agent.init(jax.random.PRNGKey(0))
  paths, tree = jax.tree_util.tree_flatten_with_path(state.policy)
  keys = jax.random.split(jax.random.PRNGKey(1), len(paths))
  leaves = [x if "kernel" in jax.tree_util.keystr(path) else
            x + 0.2 * jax.random.normal(key, x.shape) for (path, x), key in zip(paths, keys)]
  return cfg, agent, state._replace(policy=jax.tree.unflatten(tree, leaves))


def observations(n=512):
  return np.asarray(2 * jax.random.normal(jax.random.PRNGKey(2), (n, O)))


def saved_policy(tmp_path, name="d4pg", dtype="float32", **overrides):
  cfg, agent, state = trained_like(name, dtype, **overrides)
  policy = export.policy_of(name, cfg, state.policy, O, A, task={"env": "Hopper"})
  return export.save(policy, str(tmp_path / "policy.npz")), agent, state


@pytest.mark.parametrize("dtype", ["float32", "bfloat16"])
@pytest.mark.parametrize("name, overrides", AGENTS)
def test_actions_equal_the_jax_policy(tmp_path, name, overrides, dtype):
  path, agent, state = saved_policy(tmp_path, name, dtype, **overrides)
  policy = export.load(path)
  obs = observations()
  want = np.asarray(jax.jit(agent.policy)(state, obs))
  got = policy(obs)
  assert got.shape == (512, A) and got.dtype == np.float32
  assert 0.05 < np.mean(np.abs(want) < 0.99)  # not all saturated
  if dtype == "float32":
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-5)
  else:
    # bfloat16 keeps 8 significant bits. The file rounds where XLA's program does, so almost
    # every action agrees to float32's precision; where float32 sums in another order flip one
    # rounding, an action may differ by about one bfloat16 step (2^-8) of an intermediate.
    diff = np.abs(got - want)
    assert diff.max() <= 4e-3
    assert np.mean(diff <= 1e-5) >= 0.98
  np.testing.assert_allclose(policy(obs[0]), got[0], rtol=0, atol=1e-6)  # one observation


@pytest.mark.parametrize("dtype", ["float32", "bfloat16"])
@pytest.mark.parametrize("name, overrides", [("d4pg", {}), ("mpo", {"action_bounds": "squash"}),
                                             ("dmpo", {})])
def test_the_onnx_model_acts_as_the_file(tmp_path, name, overrides, dtype):
  onnxruntime = pytest.importorskip("onnxruntime")
  from mjx_hopper.faces import export_onnx
  path, _, _ = saved_policy(tmp_path, name, dtype, **overrides)
  onnx_path = export_onnx.write(path, str(tmp_path / "policy.onnx"))
  session = onnxruntime.InferenceSession(onnx_path, providers=["CPUExecutionProvider"])
  obs = observations()
  got = session.run(["action"], {"obs": obs})[0]
  want = export.load(path)(obs)
  diff = np.abs(got - want)
  # As the file against JAX (test_actions_equal_the_jax_policy): float32 sums in another order
  # may flip a bfloat16 rounding.
  assert diff.max() <= (1e-5 if dtype == "float32" else 4e-3)
  assert np.mean(diff <= 1e-5) >= 0.98
  assert session.run(["action"], {"obs": obs[:1]})[0].shape == (1, A)


def test_load_needs_no_jax(tmp_path):
  path, _, _ = saved_policy(tmp_path)
  code = ("import sys, numpy as np\n"
          "from mjx_hopper.faces import export\n"
          f"policy = export.load({path!r})\n"
          f"print(policy(np.zeros({O})).shape, policy(np.zeros((4, {O}))).shape)\n"
          "print(sorted(m for m in sys.modules if m.split('.')[0] in ('jax', 'jaxlib', 'flax')))")
  out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
  assert out.stdout.splitlines() == [f"({A},) (4, {A})", "[]"]


@pytest.mark.parametrize("name, dtype", [("d4pg", "bfloat16"), ("mpo", "float32")])
def test_the_docs_numpy_lines_run_the_file(tmp_path, name, dtype):
  path, _, _ = saved_policy(tmp_path, name, dtype)
  with open(os.path.join(os.path.dirname(__file__), "..", "docs", "export.md")) as f:
    blocks = f.read().split("```python\n")
  code = next(block.split("```")[0] for block in blocks if "def act(" in block)
  scope = {}
  exec(code.replace('"policy.npz"', repr(path)), scope)  # noqa: S102 - the docs' own lines
  obs = observations()
  np.testing.assert_array_equal(scope["act"](obs), export.load(path)(obs))


def test_bad_files_and_observations_are_one_line_errors(tmp_path):
  path, _, _ = saved_policy(tmp_path)
  with np.load(path) as f:
    arrays = dict(f)
  meta = json.loads(str(arrays.pop("meta")))
  newer = str(tmp_path / "newer.npz")
  np.savez(newer, meta=np.array(json.dumps({**meta, "format": export.FORMAT + 1})), **arrays)
  with pytest.raises(ValueError, match=f"has policy format {export.FORMAT + 1} .* reads format "
                                       f"{export.FORMAT}: load it with mjx_hopper "):
    export.load(newer)
  np.savez(str(tmp_path / "other.npz"), w0=np.zeros(3))
  with pytest.raises(ValueError, match=r"other.npz is not a policy exported by mjx_hopper: it "
                                       r"holds the arrays \['w0'\] and no 'meta' entry$"):
    export.load(str(tmp_path / "other.npz"))
  with pytest.raises(ValueError, match=r"meta lacks \['agent', "):
    export.load(str(saved_npz(tmp_path / "empty_meta.npz", meta=np.array('{"format": 1}'))))
  cut = saved_npz(tmp_path / "wrong_width.npz", **{**arrays, "w1": arrays["w1"][:-1]},
                  meta=np.array(json.dumps(meta)))
  with pytest.raises(ValueError, match=r"layer 1's weights \(63, 64\) do not take 64 inputs"):
    export.load(str(cut))
  with pytest.raises(ValueError, match=rf"takes observations of shape \({O},\) or \(N, {O}\), "
                                       r"got \(2, 14\)"):
    export.load(path)(np.zeros((2, 14)))


def saved_npz(path, **arrays):
  np.savez(str(path), **arrays)
  return path


def test_a_file_that_is_not_a_policy_is_refused_in_one_line_and_never_unpickled(tmp_path,
                                                                                 capsys):
  exported, _, _ = saved_policy(tmp_path)
  with open(exported, "rb") as f:
    whole = f.read()
  files = {"garbage.npz": os.urandom(4096), "truncated.npz": whole[:len(whole) // 2],
           "pickled.npz": pickle.dumps({"w0": np.zeros(3)})}
  for name, data in files.items():
    (tmp_path / name).write_bytes(data)
  saved_npz(tmp_path / "objects.npz", meta=np.array([{"format": 1}], dtype=object))
  np.save(tmp_path / "one.npy", np.zeros(3))
  expected = "is not a policy file written by `mjx-hopper export` \\(an .npz\\): "
  for name, why in [("garbage.npz", "NumPy cannot read it"), ("truncated.npz", "NumPy cannot "
                    "read it"), ("pickled.npz", "NumPy cannot read it"),
                    ("objects.npz", "its arrays cannot be read"), ("one.npy", "it holds one "
                                                                              "array")]:
    with pytest.raises(ValueError, match=f"^{tmp_path / name} {expected}{why}") as error:
      export.load(str(tmp_path / name))
    assert "\n" not in str(error.value) and "allow_pickle" not in str(error.value)
  # The command line says the same in one line, before JAX builds anything.
  with pytest.raises(SystemExit, match=f"^mjx-hopper eval: {tmp_path / 'garbage.npz'} "
                                       f"{expected}NumPy cannot read it"):
    cli.main(["--cpu-devices", "2", "eval", "--policy", str(tmp_path / "garbage.npz")])


def test_a_task_from_a_notebook_asks_for_its_class(tmp_path):
  cfg, _, state = trained_like("d4pg", "float32")
  policy = export.policy_of("d4pg", cfg, state.policy, O, A,
                            task={"env": "__main__:HighJump", "episode_steps": 30,
                                  "env_settings": {}})
  with pytest.raises(ValueError, match="__main__:HighJump, a task defined in a notebook .* "
                                       "pass its class as --env module:Class"):
    export.make_env(policy)
  assert export.make_env(policy, env="Hopper").episode_steps == 30


# ---- From a checkpoint ---------------------------------------------------------------------

@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
  """A tiny D4PG run's folder (two evaluations, checkpoints with the best's agent)."""
  out = tmp_path_factory.mktemp("run")
  loop.run(dataclasses.replace(TINY, out_dir=str(out)), progress=False, print_fn=lambda _: None)
  return out


def test_a_run_in_progress_is_read_without_taking_its_lock(run_dir, tmp_path):
  """eval, export and extract read a folder whose lock a live run holds (this process: taking
  the lock again would be refused), and leave the lock as it is."""
  directory, quiet = str(run_dir / "checkpoints"), lambda _: None
  with runlock.hold(str(run_dir), quiet) as lock:
    with open(lock) as f:
      held = f.read()
    export.export_checkpoint(directory, str(tmp_path / "policy.npz"), print_fn=quiet)
    checkpoints.load_policy(directory, print_fn=quiet)
    checkpoints.extract(directory, 0, str(tmp_path / "member0"), print_fn=quiet)
    with open(lock) as f:
      assert f.read() == held


def test_export_of_a_run_acts_as_its_policy_and_records_its_task(run_dir, tmp_path):
  lines = []
  directory = str(run_dir / "checkpoints")
  out = export.export_checkpoint(directory, str(tmp_path / "policy.npz"), print_fn=lines.append)
  policy = export.load(out)
  cfg, agent_state, trainer = checkpoints.load_policy(directory, print_fn=lambda _: None)
  obs = observations()
  np.testing.assert_allclose(policy(obs), np.asarray(jax.jit(trainer.agent.policy)(
      agent_state, obs)), rtol=0, atol=1e-5)
  mngr = store.manager(directory)
  record = store.read_config(mngr, mngr.latest_step())["record"]
  meta = policy.meta
  assert meta["task"] == {"env": "Hopper", "episode_steps": 30, "env_settings": {}}
  assert (meta["observation_size"], meta["action_size"]) == (O, A)
  assert meta["evaluation"] == {"which": "best", "return": record["best_return"][0],
                                "env_steps": record["best_env_steps"][0], "episodes": 2}
  assert meta["format"] == export.FORMAT and meta["checkpoint_format"] == store.items.FORMAT
  assert meta["versions"]["mjx_hopper"] == mjx_hopper.__version__
  assert meta["agent"] == "d4pg" and meta["run_config"]["agent"] == "d4pg"
  assert lines[-1].startswith(f"exported the best policy of {directory}, return ")
  latest = export.load(export.export_checkpoint(directory, str(tmp_path / "latest.npz"),
                                                which="latest", print_fn=lambda _: None))
  assert latest.meta["evaluation"] == {"which": "latest", "return": None, "env_steps": 80,
                                       "episodes": 2}


def test_an_exported_file_evaluates_and_films_as_its_checkpoint(run_dir, tmp_path):
  directory = str(run_dir / "checkpoints")
  path = export.export_checkpoint(directory, str(tmp_path / "policy.npz"),
                                  print_fn=lambda _: None)
  lines = []
  video = str(tmp_path / "policy.mp4")
  result = export.evaluate_file(path, episodes=2, seed=3, video_path=video,
                                print_fn=lines.append)
  cfg, agent_state, trainer = checkpoints.load_policy(directory, print_fn=lambda _: None)
  # The run's own evaluation program, of one member, from the same key.
  want = jax.device_get(trainer.evaluate(jax.tree.map(lambda x: x[None], agent_state),
                                         jax.random.PRNGKey(3)[None]))
  want = jax.tree.map(lambda x: x[0], want)
  np.testing.assert_array_equal(result["length"], want["length"])
  np.testing.assert_allclose(result["return"], want["return"], rtol=1e-4, atol=1e-4)
  assert os.path.getsize(video) > 0
  assert lines[0].startswith(f"Hopper / d4pg ({path}): return ")
  assert lines[1].startswith("video of episode 0 (")


def test_export_without_a_checkpoint_writes_nothing(tmp_path):
  out = tmp_path / "policy.npz"
  with pytest.raises(FileNotFoundError, match="no checkpoint directory"):
    export.export_checkpoint(str(tmp_path / "missing"), str(out))
  assert not (tmp_path / "missing").exists()
  (tmp_path / "empty").mkdir()
  with pytest.raises(FileNotFoundError, match="no checkpoint in"):
    export.export_checkpoint(str(tmp_path / "empty"), str(out))
  assert sorted(os.listdir(tmp_path)) == ["empty"] and os.listdir(tmp_path / "empty") == []


def test_export_of_a_sweep_needs_a_member_it_holds(tmp_path):
  directory = str(tmp_path / "ckpt")
  mngr = store.manager(directory)
  store.save(mngr, fake_state(1), {**TINY.to_json(), "member_indices": [0, 1]})
  store.wait_and_record(mngr)
  out = tmp_path / "policy.npz"
  with pytest.raises(ValueError, match="holds a sweep of 2 members: give a member's index "
                                       r"\(--member INDEX, or --member best\)"):
    export.export_checkpoint(directory, str(out))
  with pytest.raises(ValueError, match=r"member 5 is not in .*: it holds members \[0, 1\]"):
    export.export_checkpoint(directory, str(out), member=5)
  with pytest.raises(ValueError, match="no evaluation was saved yet, so no member is the best"):
    export.export_checkpoint(directory, str(out), member="best")
  assert not out.exists()


def test_export_of_a_newer_checkpoint_format_writes_nothing(tmp_path, monkeypatch):
  directory = str(tmp_path / "ckpt")
  monkeypatch.setattr(store.items, "FORMAT", store.items.FORMAT + 1)
  mngr = store.manager(directory)
  store.save(mngr, fake_state(1), CONFIG)
  store.wait_and_record(mngr)
  monkeypatch.undo()
  with pytest.raises(store.FormatMismatch, match=f"has format {store.items.FORMAT + 1}"):
    export.export_checkpoint(directory, str(tmp_path / "policy.npz"))
  assert not (tmp_path / "policy.npz").exists()


def test_the_cli_exports_and_evaluates_the_file(run_dir, tmp_path, capsys):
  from mjx_hopper.faces import cli
  out, video = tmp_path / "policy.npz", tmp_path / "policy.mp4"
  cli.main(["--cpu-devices", "2", "export", "--checkpoint", str(run_dir / "checkpoints"),
            "--out", str(out)])
  cli.main(["--cpu-devices", "2", "eval", "--policy", str(out), "--episodes", "2", "--video",
            str(video)])
  text = capsys.readouterr().out
  assert "exported the best policy" in text and "over 2 episodes" in text
  assert video.stat().st_size > 1000
  with pytest.raises(SystemExit, match="mjx-hopper export: .*no checkpoint"):
    cli.main(["--cpu-devices", "2", "export", "--checkpoint", str(tmp_path / "none"),
              "--out", str(tmp_path / "x.npz")])
  assert not (tmp_path / "x.npz").exists()
