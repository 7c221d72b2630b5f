"""Programs kept as traced (core.kept): a later build reads the program instead of tracing, and
runs it as the function would; anything that shapes the program otherwise, or a damaged file,
is traced afresh."""

import dataclasses
import os
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.sharding import NamedSharding, PartitionSpec as P

import configs
from mjx_hopper import agents
from mjx_hopper.core import kept
from mjx_hopper.run import loop, trainers
from mjx_hopper.settings.plan import resolve


class State(NamedTuple):
  x: jax.Array
  parts: dict


@pytest.fixture
def cache(tmp_path):
  """A compile-cache folder of the test's own, and no programs in memory."""
  before = jax.config.jax_compilation_cache_dir
  jax.config.update("jax_compilation_cache_dir", str(tmp_path))
  kept.forget()
  yield tmp_path
  kept.forget()
  jax.config.update("jax_compilation_cache_dir", before)


def make(identity, traced):
  """A kept function of a sharded state, which counts its traces in `traced`."""
  mesh = jax.sharding.Mesh(np.array(jax.devices()), ("d",))
  rows = NamedSharding(mesh, P("d"))

  def step(state, scale):
    traced.append(1)
    y = jnp.sin(state.x) * scale + state.parts["b"].sum()
    return State(y, {"b": state.parts["b"] + 1}), {"mean": y.mean()}
  fn = kept.jit(step, identity, "step", in_shardings=(State(rows, {"b": rows}), None),
                out_shardings=(State(rows, {"b": rows}), None), donate_argnums=0)
  fn.step = step
  return fn, rows


def state(rows, n=8):
  return jax.device_put(State(jnp.arange(n, dtype=jnp.float32), {"b": jnp.ones(n)}),
                        State(rows, {"b": rows}))


def test_a_later_build_runs_the_kept_program_without_tracing(cache):
  traced = []
  first, rows = make("a", traced)
  given = state(rows)
  want_state, want = jax.device_get(first(given, 2.0))
  assert given.x.is_deleted()  # donated, as the function's jit asks
  assert len(traced) == 1 and len(os.listdir(cache / kept.FOLDER)) == 1
  plain = jax.jit(first.step)  # the function as jitted (its trace cached)
  jax.tree.map(np.testing.assert_array_equal, (want_state, want),
               jax.device_get(plain(state(rows), 2.0)))

  same, _ = make("a", traced)  # built again in this process: the program in memory
  jax.tree.map(np.testing.assert_array_equal, (want_state, want),
               jax.device_get(same(state(rows), 2.0)))
  assert len(traced) == 1
  kept.forget()
  again, _ = make("a", traced)  # as a new process builds it: nothing in memory
  out_state, out = again(state(rows), 2.0)
  assert len(traced) == 1  # read, not traced
  assert out_state.x.sharding == rows and isinstance(out_state, State)
  jax.tree.map(np.testing.assert_array_equal, (want_state, want), jax.device_get((out_state,
                                                                                out)))
  # Lowered from shapes, as a run's start does, and compiled: the same program.
  shapes = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=x.sharding),
                        state(rows))
  kept.forget()
  lowered = make("a", traced)[0].lower(shapes, 2.0)
  assert len(traced) == 1
  np.testing.assert_array_equal(lowered.compile()(state(rows), 2.0)[1]["mean"], want["mean"])
  # The same function not kept (a task of one's own) is the same program, which the compile
  # cache serves to both.
  unkept = make(None, traced)[0].lower(shapes, 2.0)
  assert len(traced) == 2
  assert unkept.as_text(debug_info=False) == lowered.as_text(debug_info=False)
  assert len(os.listdir(cache / kept.FOLDER)) == 1


def test_another_identity_or_shape_is_traced_afresh(cache):
  traced = []
  fn, rows = make("a", traced)
  fn(state(rows), 2.0)
  make("b", traced)[0](state(rows), 2.0)
  assert len(traced) == 2
  kept.forget()
  make("a", traced)[0](state(rows, n=4), 2.0)
  assert len(traced) == 3
  kept.forget()
  make("a", traced)[0](state(rows), np.float32(2.0))  # a strong type, where 2.0 is weak
  assert len(traced) == 4
  with jax.default_matmul_precision("highest"):  # a JAX setting that changes the program
    fn(state(rows), 2.0)
  assert len(traced) == 5
  assert len(os.listdir(cache / kept.FOLDER)) == 5


def test_xla_flags_are_read_as_xla_reads_them(cache, monkeypatch):
  # The CLI's `setup(cpu_devices=...)` writes $XLA_FLAGS back with single spaces: the same flags
  # are the same program; another flag is another.
  traced, flags = [], os.environ.get("XLA_FLAGS", "")
  for written, count in ((flags, 1), ("  " + flags.replace(" ", "   ") + " ", 1),
                         (flags + " --xla_cpu_enable_fast_math=false", 2)):
    kept.forget()
    monkeypatch.setenv("XLA_FLAGS", written)
    fn, rows = make("a", traced)
    fn(state(rows), 2.0)
    assert len(traced) == count, written


def test_a_damaged_file_is_traced_afresh_and_written_again(cache):
  traced = []
  fn, rows = make("a", traced)
  want = jax.device_get(fn(state(rows), 2.0))
  path, = (cache / kept.FOLDER).iterdir()
  path.write_bytes(path.read_bytes()[:100])
  kept.forget()
  got = make("a", traced)[0](state(rows), 2.0)
  assert len(traced) == 2
  jax.tree.map(np.testing.assert_array_equal, want, jax.device_get(got))
  kept.forget()
  make("a", traced)[0](state(rows), 2.0)
  assert len(traced) == 2  # the file was written whole again


def test_without_a_compile_cache_nothing_is_kept(cache):
  jax.config.update("jax_compilation_cache_dir", None)
  traced = []
  fn, rows = make("a", traced)
  fn(state(rows), 2.0)
  kept.forget()
  make("a", traced)[0](state(rows), 2.0)
  assert len(traced) == 2


def test_under_gspmd_the_function_runs_as_jitted(cache):
  traced = []
  fn, rows = make("a", traced)
  want = jax.device_get(fn(state(rows), 2.0))
  before = jax.config.jax_use_shardy_partitioner
  jax.config.update("jax_use_shardy_partitioner", False)
  try:
    jax.tree.map(np.testing.assert_array_equal, want,
                 jax.device_get(make("b", traced)[0](state(rows), 2.0)))
  finally:
    jax.config.update("jax_use_shardy_partitioner", before)
  assert len(traced) == 2 and len(os.listdir(cache / kept.FOLDER)) == 1  # "b" not kept


def identity(cfg) -> str | None:
  return resolve(cfg).identity


def test_a_trainer_is_kept_only_for_the_packages_own_task_and_agent(monkeypatch):
  cfg = configs.TINY
  assert identity(cfg) == repr(resolve(cfg).program_key)
  # Dynamic settings are data of the same programs; n-step's window and the networks shape them.
  overrides = cfg.agent_overrides
  same = dataclasses.replace(cfg, agent_overrides={**overrides, "learning_rate": 0.5,
                                                   "discount": 0.9, "vmax": 900.0})
  assert identity(same) == identity(cfg)
  for shaping in ({"n_step": 1}, {"critic_layers": (8,)}):
    assert identity(dataclasses.replace(cfg, agent_overrides={**overrides, **shaping})
                    ) != identity(cfg)

  class Mine(type(cfg.make_env())):  # a task of one's own may change under the same name
    pass
  assert identity(dataclasses.replace(cfg, env=Mine)) is None
  d4pg = agents.spec("d4pg")  # and an agent registered from code of one's own
  monkeypatch.setitem(agents._AGENTS, "d4pg", d4pg._replace(make=lambda *a: d4pg.make(*a)))
  assert identity(cfg) is None


def test_a_second_run_of_the_same_shapes_traces_and_compiles_none_of_its_programs(
    tmp_path, monkeypatch):
  # The product's build (not the suite's memo): another seed, learning rate and noise are the
  # same programs (the plan's `program_key`), which the process already holds, traced and compiled.
  monkeypatch.setattr(trainers, "build", trainers.build.__wrapped__)
  heavy = ("chunk", "refill", "evaluate", "init_member")
  events = []

  def listen(event, secs, fun_name="", **_):
    if any(name in fun_name for name in heavy):
      events.append((event.rsplit("/", 1)[-1], fun_name))
  for seed in (0, 1):
    events.clear()
    if seed == 1:
      jax.monitoring.register_event_duration_secs_listener(listen)
    try:
      dynamic = {"learning_rate": 1e-3 * (1 + seed), "sigma": 0.2 + 0.1 * seed}
      loop.run(dataclasses.replace(configs.TINY, seed=seed, total_env_steps=80,
                                   agent_overrides={**configs.TINY.agent_overrides, **dynamic},
                                   out_dir=str(tmp_path / str(seed))),
               progress=False, print_fn=lambda line: None)
    finally:
      if seed == 1:
        jax.monitoring.unregister_event_duration_listener(listen)
  assert events == []
