"""Sweeps: members of one compiled program, each the single run of its settings, resumable,
extractable, and spread over processes with jax.distributed."""

import contextlib
import csv
import dataclasses
import os
import re
import signal
import socket
import subprocess
import sys
import time

import jax
import numpy as np
import pytest

from mjx_hopper import store
from mjx_hopper.core import train
from mjx_hopper.core.pbt import exploit_explore
from mjx_hopper.faces import cli
from mjx_hopper.process import ledger
from mjx_hopper.run import checkpoints, loop, sweep, trainers
from mjx_hopper.settings.plan import resolve
from mjx_hopper.settings.training import PBT
from configs import JUMP, JUMP_ARGS, POPULATION, TINY, TINY_ARGS
from test_train import member

# The populations trained here are of the notebook's high jump (configs.JUMP): four members of it
# (configs.POPULATION) are the programs of the notebook's population (its PBT cell), which the
# compile cache then serves to the notebook.


def run_chunks(trainer, state, chunks=2):
  for _ in range(chunks):
    state, metrics = trainer.train_chunk(state)
  return jax.device_get(state), jax.device_get(metrics)


def assert_same(a, b):
  jax.tree.map(lambda x, y: np.testing.assert_array_equal(np.asarray(x), np.asarray(y)), a, b)


def assert_close(a, b, rtol):
  """Every float leaf of `a` within rtol of its largest magnitude in `b` (plus 1), the others
  equal. Members vmapped two to a device take XLA's batched products, whose sums may be
  ordered otherwise than a single run's, and chunks of learning and physics grow those last-bit
  differences: to about 1e-3 of a leaf's scale mostly after two chunks, and more in the few
  observations where an env's contacts went otherwise, which differ by CPU model. Compared
  over a chunk, they stay within the tolerance."""
  for (path, x), y in zip(jax.tree_util.tree_leaves_with_path(a), jax.tree.leaves(b)):
    x, y = np.asarray(x), np.asarray(y)
    if x.dtype.kind != "f":
      np.testing.assert_array_equal(x, y, err_msg=jax.tree_util.keystr(path))
    elif x.size:
      np.testing.assert_allclose(x, y, rtol=0, atol=rtol * (np.abs(y).max() + 1),
                                 err_msg=jax.tree_util.keystr(path))


@pytest.fixture(scope="module")
def single():
  """The trainer of a single JUMP run on one device, as a sweep's member is laid out (a
  single run over two devices gives each its own envs' keys and replay). A member's seed and
  swept values are data, init's inputs, so this one program is every member's single run."""
  base = trainers.build(resolve(JUMP, 1))
  ledger.note("trainer", "HighJump d4pg x1 on one device")
  return train.make_trainer(base.env, base.agent, JUMP.train, JUMP.eval_episodes,
                            devices=jax.local_devices()[:1])


def single_run(single, chosen, chunks=2):
  """Host (state, metrics) of the single run of one member's seed and swept values."""
  hparams = {name: [value] for name, value in chosen.items() if name != "seed"}
  return run_chunks(single, single.init([chosen["seed"]], hparams), chunks)


def stop_after_first_chunk(line):
  """A print_fn that asks the run to stop (as Ctrl-C would) once the first chunk is logged."""
  if line.startswith("[train]"):
    os.kill(os.getpid(), signal.SIGTERM)


def test_sweep_writes_results_resumes_exactly_and_extracts(single, tmp_path, capsys):
  # 2 seeds x 2 sigmas = 4 members, two on each device (under vmap).
  cfg = dataclasses.replace(POPULATION, total_env_steps=80, out_dir=str(tmp_path / "straight"))
  straight = loop.run(cfg, progress=False)
  split_cfg = dataclasses.replace(cfg, out_dir=str(tmp_path / "split"))
  stopped = loop.run(split_cfg, progress=False, print_fn=stop_after_first_chunk)
  assert stopped.trainer.env_steps(stopped.state) == 40
  after_one = jax.device_get(stopped.state)
  resumed = loop.run(split_cfg, progress=False)
  assert_same(jax.device_get(straight.state), jax.device_get(resumed.state))
  # Two members per device run under vmap: within a tolerance of their single runs, and not
  # of the run of another sigma from the same seed (members 0 and 2). Over one chunk: a second
  # lets an episode's contacts part on some CPUs (2 of 960 observations, on an AMD host).
  singles = [member(single_run(single, chosen, chunks=1)[0])
             for chosen in cfg.member_settings()]
  for i, one in enumerate(singles):
    assert_close(member(after_one, i), one, rtol=5e-2)
  with pytest.raises(AssertionError):
    assert_close(member(after_one, 0), singles[2], rtol=5e-2)
  # A single run with its sigma given as init's data is the single run of that setting as a
  # user starts it (member 3 has JUMP's own sigma and seed 1), bit for bit.
  assert cfg.member_settings()[3] == {"seed": 1, "sigma": JUMP.agent_config().sigma}
  user_path = run_chunks(single, trainers.init(resolve(dataclasses.replace(JUMP, seed=1)), single,
                                               [{"seed": 1}]), chunks=1)
  assert_same(user_path, single_run(single, cfg.member_settings()[3], chunks=1))

  with open(tmp_path / "straight" / "log.csv") as f:
    rows = list(csv.DictReader(f))
  evals = [r for r in rows if r["kind"] == "eval"]
  assert sorted((int(r["member"]), int(r["env_steps"])) for r in evals) == [
      (m, s) for m in range(4) for s in (40, 80)]
  assert {(int(r["member"]), int(r["seed"]), float(r["sigma"])) for r in evals} == {
      (0, 0, 0.1), (1, 1, 0.1), (2, 0, 0.3), (3, 1, 0.3)}
  out = capsys.readouterr().out
  assert "| rank | setting |" in out and "sigma=0.1" in out and "sigma=0.3" in out
  assert (tmp_path / "straight" / "curves.png").stat().st_size > 10_000

  # Member 2 (seed 0, sigma 0.3) becomes a single run's checkpoint.
  target = checkpoints.extract(str(tmp_path / "straight" / "checkpoints"), 2, str(tmp_path / "m2"))
  one_cfg, one_state, _ = checkpoints.restore(target)
  assert (one_cfg.seed, one_cfg.agent_overrides["sigma"], one_cfg.seeds, one_cfg.grid) == (
      0, 0.3, (), {})
  assert_same(member(one_state), member(straight.state, 2))
  with pytest.raises(ValueError, match="already holds a checkpoint"):
    checkpoints.extract(str(tmp_path / "straight" / "checkpoints"), 2, str(tmp_path / "m2"))
  with pytest.raises(ValueError, match=r"member 7 is not in .*: it holds members \[0, 1, 2, 3\]"):
    checkpoints.extract(str(tmp_path / "straight" / "checkpoints"), 7, str(tmp_path / "m7"))


@pytest.mark.parametrize("grid, message", [
    ({"learning_rat": (1e-4,)}, "unknown setting 'learning_rat' in the sweep; settings that can "
                                "be swept are .*'learning_rate'"),
    ({"learning_rate": ()}, "the sweep's 'learning_rate' needs a non-empty list of values"),
    ({"policy_layers": ((16,), (32,))}, "'policy_layers' is structural .* run one sweep per "
                                        "value"),
    ({"batch_size": (8, 16)}, "'batch_size' is structural"),
    ({"sigma": (0.1, 0.1)}, r"the sweep's 'sigma' repeats a value: \[0.1, 0.1\]"),
    ({"learning_rate": (1e-4, -1.0)}, "learning_rate must be > 0, got -1.0"),
    ({"replay_ratio": (2.0, 1.5)}, "must be a whole number of updates >= 1, got 1.5"),
])
def test_bad_sweep_specs(grid, message):
  with pytest.raises(ValueError, match=message):
    dataclasses.replace(TINY, grid=grid)


def test_bad_seeds_and_cli_spec(capsys):
  with pytest.raises(ValueError, match=r"seeds must be distinct integers, got \[1, 1\]"):
    dataclasses.replace(TINY, seeds=(1, 1))
  with pytest.raises(SystemExit, match="'critic_layers' is structural"):
    cli.main([*TINY_ARGS[:2], "sweep", *TINY_ARGS[3:], "--set", "critic_layers=(16,),(32,)"])


def reference_pbt_step(returns, diverged, values, ranges, quanta, pbt, rng):
  """PBT's step written out plainly: the healthy members (not diverged, a finite return) by
  return, best first, then the others; each of the worst `count` (and every unhealthy member)
  that is not a source takes a random one of the best `count` healthy members, and each setting
  is moved by a random factor, snapped to its quantum (one quantum at least), and clipped."""
  S = len(returns)
  healthy = [m for m in range(S) if not diverged[m] and np.isfinite(returns[m])]
  ranked = sorted(healthy, key=lambda m: (-returns[m], m)) + [
      m for m in range(S) if m not in healthy]
  count = max(1, int(S * pbt.fraction))
  pool = [m for m in ranked[:count] if m in healthy]
  sources, new = list(range(S)), {k: list(v) for k, v in values.items()}
  if not pool:
    return sources, new
  replaced = ranked[S - max(count, S - len(healthy)):]
  for m in replaced:
    if m in pool:
      continue
    source = pool[int(rng.integers(len(pool)))]
    sources[m] = source
    for name in values:
      now = float(values[name][source])
      moved = now * pbt.factors[int(rng.integers(len(pbt.factors)))]
      if name in quanta:
        q = quanta[name]
        snapped = round(moved / q) * q
        if snapped == now:
          snapped = now + q if moved > now else now - q
        moved = snapped
      new[name][m] = min(max(moved, ranges[name][0]), ranges[name][1])
  return sources, new


def test_exploit_explore_matches_a_plain_reference_on_random_populations():
  pbt = PBT(fraction=0.3, factors=(0.5, 0.8, 1.25, 2.0))
  ranges = {"learning_rate": (1e-5, 1e-2), "n_step": (1, 7), "replay_ratio": (0.5, 8.0)}
  quanta = {"n_step": 1, "replay_ratio": 0.25}
  draw = np.random.default_rng(0)
  for trial in range(200):
    S = int(draw.integers(2, 12))
    returns = draw.normal(1000, 300, S)
    returns[draw.random(S) < 0.1] = np.nan
    diverged = draw.random(S) < 0.2
    values = {"learning_rate": 10 ** draw.uniform(-5, -2, S).astype(np.float32),
              "n_step": draw.integers(1, 8, S).astype(np.int32),
              "replay_ratio": (draw.integers(2, 33, S) * 0.25).astype(np.float32)}
    sources, new = exploit_explore(pbt, returns, diverged, values, ranges, quanta,
                                         np.random.default_rng(trial))
    want_sources, want = reference_pbt_step(returns, diverged, values, ranges, quanta, pbt,
                                            np.random.default_rng(trial))
    np.testing.assert_array_equal(sources, want_sources)
    for name in values:
      assert new[name].dtype == values[name].dtype
      np.testing.assert_allclose(new[name], np.asarray(want[name], values[name].dtype),
                                 rtol=1e-6)
    # Every unhealthy member is replaced (while there is a healthy one), and only healthy
    # members are copied.
    lost, replaced = diverged | ~np.isfinite(returns), sources != np.arange(S)
    assert replaced[lost].all() or lost.all()
    assert not lost[sources].any() or lost.all()
    assert replaced.sum() >= min(max(1, int(S * 0.3)), (~lost).sum())


def test_exploit_explore_copies_only_healthy_members():
  # Three of four diverged: the one healthy member is every copy's source, whatever the ranks.
  pbt = PBT(fraction=0.5)
  sources, new = exploit_explore(
      pbt, np.array([100.0, 5.0, 3.0, 1.0]), np.array([False, True, True, True]),
      {"sigma": np.array([0.3, 0.1, 0.2, 0.4], np.float32)}, {"sigma": (0.1, 0.4)}, {},
      np.random.default_rng(0))
  assert list(sources) == [0, 0, 0, 0]
  assert set(np.round(new["sigma"][1:], 6)) <= {0.24, 0.375}
  everyone_lost = exploit_explore(pbt, np.ones(4), np.ones(4, bool),
                                        {"sigma": np.ones(4, np.float32)}, {"sigma": (0.1, 1.0)},
                                        {}, np.random.default_rng(0))
  assert list(everyone_lost[0]) == [0, 1, 2, 3]


def test_bad_pbt_specs():
  with pytest.raises(ValueError, match=r"PBT's fraction must be in \(0, 0.5\], got 0.7"):
    PBT(fraction=0.7)
  with pytest.raises(ValueError, match="PBT perturbs the grid's settings"):
    dataclasses.replace(TINY, seeds=(0, 1), pbt=PBT())
  with pytest.raises(ValueError, match="PBT cannot perturb 'sigma': the grid has one value"):
    dataclasses.replace(TINY, seeds=(0, 1), grid={"sigma": (0.3,)}, pbt=PBT())
  with pytest.raises(ValueError, match="PBT needs at least 2 members"):
    dataclasses.replace(TINY, pbt=PBT(bounds={"sigma": (0.1, 0.5)}), grid={"sigma": (0.3,)})
  with pytest.raises(ValueError, match="learning_rate must be > 0"):
    dataclasses.replace(TINY, grid={"learning_rate": (1e-3, 1e-2)},
                        pbt=PBT(bounds={"learning_rate": (-1.0, 1e-2)}))
  with pytest.raises(SystemExit, match="--pbt-every set"):
    cli.main([*TINY_ARGS[:2], "sweep", *TINY_ARGS[3:], "--pbt-every", "3"])


# Four members, two to a device under vmap, each device holding a sane learning rate beside an
# absurd one (members 1 and 3): the trainer of test_sweep_writes_results_resumes_exactly_and_
# extracts (four members; their sigmas and learning rates are data).
ABSURD = dataclasses.replace(JUMP, seeds=(0,), total_env_steps=120,
                             grid={"sigma": (0.1, 0.3), "learning_rate": (1e-3, 1e30)})


def test_a_diverged_member_is_frozen_and_the_others_go_on_unchanged(tmp_path, capsys):
  cfg = dataclasses.replace(ABSURD, out_dir=str(tmp_path))
  result = loop.run(cfg, progress=False)
  out = capsys.readouterr().out
  for m in (1, 3):
    assert (f"[diverged] member {m} at 40 env steps: " in out and "parameters not finite; "
            "frozen at its last finite agent" in out)
  # Members 0 and 2 run as they do beside sane neighbours, bit for bit (the same program): a
  # diverged member leaves the members vmapped with it alone.
  trainer = trainers.build(resolve(cfg))
  sane = dataclasses.replace(cfg, grid={"sigma": (0.1, 0.3), "learning_rate": (1e-3, 3e-4)})
  beside_sane, _ = run_chunks(trainer, trainers.init(resolve(sane), trainer), 3)
  for m in (0, 2):
    assert_same(member(result.state, m), member(beside_sane, m))
  # Members 1 and 3 diverged in their first chunk: their agents stay the ones they started with.
  start = trainers.init(resolve(cfg), trainer)
  for m in (1, 3):
    assert_same(member(result.state.agent, m), member(start.agent, m))
  with open(tmp_path / "log.csv") as f:
    rows = list(csv.DictReader(f))
  assert {r["member"]: r["diverged"] for r in rows} == {"0": "0", "1": "1", "2": "0", "3": "1"}
  assert "| 3 | sigma=0.1 learning_rate=1e+30 | -inf |" in out  # ranked last, marked
  assert "| 4 | sigma=0.3 learning_rate=1e+30 | -inf |" in out and "| 1 of 1 |" in out
  assert "2 diverged" in out


def test_pbt_replaces_a_diverged_member_resumes_exactly_and_extracts(tmp_path, capsys):
  cfg = dataclasses.replace(ABSURD, pbt=PBT(every=1), out_dir=str(tmp_path / "straight"))
  straight = loop.run(cfg, progress=False)
  out = capsys.readouterr().out
  # At the first evaluation the diverged members 1 and 3 each take a copy of a healthy one (the
  # best), its settings moved by a factor within the grid's bounds.
  first = next(line for line in out.splitlines() if line.startswith("[pbt] 40 env steps: "))
  copies = re.findall(r"member (\d) copies member (\d), with sigma=(\S+) "
                      r"learning_rate=(\S+?)(?:;|$)", first)
  assert [c[0] for c in copies] == ["1", "3"] and {c[1] for c in copies} <= {"0", "2"}
  assert all(0.1 <= float(c[2]) <= 0.3 and 1e-3 <= float(c[3]) <= 1.25e-3 for c in copies)
  split = dataclasses.replace(cfg, out_dir=str(tmp_path / "split"))
  loop.run(split, progress=False, print_fn=stop_after_first_chunk)
  resumed = loop.run(split, progress=False)
  assert_same(jax.device_get(straight.state), jax.device_get(resumed.state))
  assert_same(jax.device_get(straight.best), jax.device_get(resumed.best))
  np.testing.assert_array_equal(straight.best_return, resumed.best_return)
  logs = {}
  for name in ("straight", "split"):
    with open(tmp_path / name / "log.csv") as f:
      logs[name] = [(r["kind"], r["member"], r["env_steps"], r["learning_rate"], r["parent"],
                     r["diverged"]) for r in csv.DictReader(f)]
  assert logs["split"] == logs["straight"]
  for m in ("1", "3"):  # diverged at 40 (frozen, evaluated, then replaced), healthy after
    evals = [r for r in logs["straight"] if r[0] == "eval" and r[1] == m]
    assert [(r[2], r[4], r[5]) for r in evals[:1]] == [("40", m, "1")]
    assert evals[1][4] in ("0", "2") and 1e-3 <= float(evals[1][3]) <= 1.25e-3 * (1 + 1e-6)
    assert [r[5] for r in evals[1:]] == ["0", "0"]
  assert (tmp_path / "straight" / "pbt.png").stat().st_size > 10_000
  # The best member becomes a single run that eval and train take.
  target = checkpoints.extract(str(tmp_path / "straight" / "checkpoints"), "best",
                        str(tmp_path / "best"))
  best = int(np.argmax(straight.best_return))
  one_cfg, agent, _ = checkpoints.load_policy(target)
  assert one_cfg.grid == {} and one_cfg.pbt is None
  last = [r for r in logs["straight"] if r[1] == str(best)][-1]
  assert one_cfg.agent_overrides["learning_rate"] == float(last[3])
  assert_same(agent, member(straight.best, best))


# A 4-member PBT sweep: members (learning_rate, sigma) 0 (1e-3, 0.1), 1 (1e-3, 0.3),
# 2 (1e30, 0.1) and 3 (1e30, 0.3), the grid in the order of the settings (JUMP_ARGS sets the
# learning rate first); on one process of two devices, the programs of ABSURD. Members 2 and 3
# diverge in the first chunk, and PBT gives each a copy of a member on the other process at the
# second evaluation. Evaluations fall due inside chunks (every 60 env steps, a chunk being 40),
# and between PBT's steps.
PBT_SWEEP = [*JUMP_ARGS[3:], "--total-env-steps", "200",
             "--set", "sigma=0.1,0.3", "--set", "learning_rate=1e-3,1e30", "--pbt",
             "--eval-every", "60", "--pbt-every", "2"]


def free_port() -> int:
  with socket.socket() as s:
    s.bind(("localhost", 0))
    return s.getsockname()[1]


# `mjx-hopper` whose chunks take a second and whose process 1 compiles its evaluation
# $LATE_EVALUATION_S seconds late, as on a loaded machine.
LATE = [os.path.join(os.path.dirname(__file__), "late_evaluation.py")]


def start_processes(out_dir, flags, env=None, cli_=("-m", "mjx_hopper.faces.cli")
                    ) -> list[subprocess.Popen]:
  """Two processes of one CPU device each, of one sweep over JAX's distributed runtime."""
  return [subprocess.Popen([sys.executable, *cli_, "--cpu-devices", "1",
                            "sweep", *PBT_SWEEP, "--out-dir", str(out_dir), "--distributed",
                            *flags(i)], env={**os.environ, **(env(i) if env else {})},
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
          for i in range(2)]


@contextlib.contextmanager
def two_processes(out_dir, flags, env=None, cli_=("-m", "mjx_hopper.faces.cli")):
  """`start_processes`, killed (with what they printed kept) if the test ends before they do."""
  procs = start_processes(out_dir, flags, env, cli_)
  try:
    yield procs
  finally:
    for proc in procs:
      if proc.poll() is None:
        proc.kill()
      proc.communicate()


def read_until(proc, prefix: str) -> str:
  """What `proc` prints up to and including its first line that starts with `prefix`."""
  lines = []
  for line in proc.stdout:
    lines.append(line)
    if line.startswith(prefix):
      return "".join(lines)
  raise AssertionError(f"the process ended (exit {proc.wait()}) before a line {prefix!r}:\n"
                       + "".join(lines))


def finish(proc, code: int = 0) -> str:
  """The rest of what `proc` prints, once it has ended with exit status `code`."""
  out, _ = proc.communicate(timeout=600)
  assert proc.returncode == code, out
  return out


def explicit(port: int):
  return lambda i: ["--coordinator", f"localhost:{port}", "--num-processes", "2",
                    "--process-id", str(i), "--checkpoint-minutes", "0"]


def eval_rows(folder) -> list[tuple]:
  with open(folder / "log.csv") as f:
    return [(r["member"], r["env_steps"], r["eval_return"], r["sigma"], r["learning_rate"],
             r["parent"], r["diverged"]) for r in csv.DictReader(f) if r["kind"] == "eval"]


@pytest.mark.slow
@pytest.mark.timeout(1200)  # a run that compiles, then two of two processes, one compiling
def test_two_processes_train_one_population_as_one_process_through_their_faults(tmp_path):
  # The population to match: one process of two devices, straight through. On two processes
  # of one CPU device each, process 0 holds members 0 and 1 and process 1 holds 2 and 3: the
  # mesh of one process with two devices, so the same program.
  cli.main(["--cpu-devices", "2", "sweep", *PBT_SWEEP, "--out-dir", str(tmp_path / "one")])
  two = tmp_path / "two"
  ckpt_dir = str(two / "checkpoints")

  # Process 1 killed after the first save: process 0 ends in one line that names it.
  with two_processes(two, explicit(free_port())) as procs:
    read_until(procs[0], "[train] 40 env steps")
    deadline = time.monotonic() + 300
    while not (two / "checkpoints" / "5").is_dir():  # the first save, finished
      assert procs[0].poll() is None and time.monotonic() < deadline, finish(procs[0])
      time.sleep(0.05)
    procs[1].kill()
    last = finish(procs[0], code=1).strip().splitlines()[-1]
    assert last == (f"mjx-hopper: process 1 (pid {procs[1].pid} on {socket.gethostname()}) is "
                    "gone: this process ends too; run the same command on every process to "
                    "resume from the last checkpoint")
  killed = store.manager(ckpt_dir).latest_step()
  assert killed is not None and killed < 25

  # Resumed under SLURM (jax.distributed reads each process's place from SLURM's variables), to
  # the end, process 1's evaluation compiled 15 s after process 0's while both train: every
  # process takes each evaluation at the same chunk (before that choice was agreed, process 0
  # started its first evaluation while process 1 went on, and Gloo aborted process 1), and the
  # members end as one process's do, bit for bit.
  start = free_port() % 4096  # JAX's coordinator port under SLURM: job id % 4096 + 61440
  job = next(j for j in range(start, start + 4096) if _port_free(j % 4096 + 61440))
  with two_processes(two, lambda i: [], env=lambda i: {
      "SLURM_JOB_ID": str(job), "SLURM_STEP_NODELIST": "localhost", "SLURM_NTASKS": "2",
      "SLURM_PROCID": str(i), "SLURM_LOCALID": str(i), "SLURM_STEP_NUM_NODES": "1",
      "LATE_EVALUATION_S": "15"}, cli_=LATE) as procs:
    outs = [finish(proc) for proc in procs]
  assert f"resumed from {ckpt_dir}, step {killed}" in outs[0]
  assert "done: 200 env steps" in outs[0] and "done: " not in outs[1]  # process 0 says them
  assert (two / "log.csv").exists() and not (two / "process0").exists()
  _, states, _ = checkpoints.restore(ckpt_dir)
  _, one, _ = checkpoints.restore(str(tmp_path / "one" / "checkpoints"))
  assert_same(jax.device_get(states), jax.device_get(one))
  evaluations = eval_rows(two)
  assert evaluations == eval_rows(tmp_path / "one")
  grid = {"learning_rate": (1e-3, 1e30), "sigma": (0.1, 0.3)}
  rows = {}
  for name in ("one", "two"):
    with open(tmp_path / name / "log.csv") as f:
      rows[name] = list(csv.DictReader(f))
  assert sweep.population_ranking(rows["two"], grid) == sweep.population_ranking(
      rows["one"], grid)
  assert (two / "pbt.png").stat().st_size > 10_000
  assert {r[1] for r in evaluations} == {"80", "120", "200"}
  # PBT's first step, at 120 env steps (the rows after it show it): each diverged member, on
  # process 1, copies a member of process 0.
  parents = {int(r[0]): int(r[5]) for r in evaluations if r[1] == "200"}
  assert parents[2] in (0, 1) and parents[3] in (0, 1)

  # Resumed again, with settings under which the processes must still take every choice
  # together: evaluation on the host's CPU asked for (one process's choice, which a run over
  # processes declines), process 1's evaluation compiled late, and a time budget on process 0
  # alone, passed before the first chunk. On process 0's clock the run ends after that chunk
  # (a run trains at least one), and process 1 ends there too, its evaluation taken.
  port = free_port()
  with two_processes(two, lambda i: [*explicit(port)(i), "--eval-on", "host",
                                     "--total-env-steps", "100000",
                                     *(["--max-minutes", "1e-9"] if i == 0 else [])],
                     env=lambda i: {"LATE_EVALUATION_S": "5"}, cli_=LATE) as procs:
    outs = [finish(proc) for proc in procs]
  assert "done: 240 env steps" in outs[0], outs[0]
  assert sorted(int(r[0]) for r in eval_rows(two) if r[1] == "240") == [0, 1, 2, 3]
  assert store.manager(ckpt_dir).latest_step() == 30

  # Resuming on another number of processes is refused, and changes nothing.
  with pytest.raises(SystemExit, match=r"saved by a run over 2 process\(es\), and this run "
                     r"has 1: resume it on 2"):
    cli.main(["--cpu-devices", "2", "sweep", *PBT_SWEEP, "--total-env-steps", "280",
              "--out-dir", str(two)])
  assert store.manager(ckpt_dir).latest_step() == 30


def _port_free(port: int) -> bool:
  with socket.socket() as s:
    try:
      s.bind(("localhost", port))
    except OSError:
      return False
  return True


@pytest.mark.parametrize("argv, message", [
    (["--num-processes", "2", "--process-id", "0"], "add --distributed"),
    (["--distributed", "--num-processes", "2", "--process-id", "2"],
     "process id 2 is not in 0 to 1"),
    (["--distributed", "--coordinator", "nowhere", "--num-processes", "2", "--process-id", "0"],
     "the coordinator must be host:port, got 'nowhere'"),
])
def test_bad_process_flags_are_one_line(argv, message):
  with pytest.raises(SystemExit, match=message):
    cli.main([*TINY_ARGS[:2], "sweep", *TINY_ARGS[3:], "--seeds", "2", *argv])


def test_a_busy_coordinator_port_is_one_line():
  with socket.socket() as busy:
    busy.bind(("localhost", 0))
    busy.listen()
    port = busy.getsockname()[1]
    with pytest.raises(SystemExit, match=f"the coordinator address localhost:{port} is already "
                       "in use, or not this host's: choose another port"):
      cli.main([*TINY_ARGS[:2], "sweep", *TINY_ARGS[3:], "--seeds", "2", "--distributed",
                "--coordinator", f"localhost:{port}", "--num-processes", "2", "--process-id",
                "0"])

