"""The persistent compile cache is kept per CPU feature set, so that no process loads a program
compiled for a CPU it is not."""

import json
import os
import subprocess
import sys

import jax

import configs
import mjx_hopper
from mjx_hopper.process import runtime
from mjx_hopper.run import trainers
from mjx_hopper.settings.plan import resolve

# Compiles one small program with the cache in argv[1], as a CPU with features argv[2] when
# given (standing in for another machine), and prints where the cache went and JAX's cache
# hits and misses.
PROGRAM = """
import json, sys
import jax, jax.numpy as jnp
import mjx_hopper
if len(sys.argv) > 2:
  mjx_hopper.process.runtime._cpu_features = lambda: sys.argv[2]
directory = mjx_hopper.setup(sys.argv[1])
events = []
jax.monitoring.register_event_listener(lambda name, **kwargs: events.append(name))
jax.jit(lambda x: jnp.sin(x) @ x.T + 1.0)(jnp.ones((8, 8))).block_until_ready()
print(json.dumps({"directory": directory,
                  "hits": events.count("/jax/compilation_cache/cache_hits"),
                  "misses": events.count("/jax/compilation_cache/cache_misses")}))
"""


def compile_once(cache, *features):
  done = subprocess.run([sys.executable, "-c", PROGRAM, str(cache), *features], check=True,
                        capture_output=True, text=True)
  return json.loads(done.stdout.strip().splitlines()[-1])


def test_cpu_key_names_the_feature_set(monkeypatch):
  monkeypatch.setattr(runtime, "_cpu_features", lambda: "avx2 fma sse4_2")
  key = mjx_hopper.cpu_key()
  assert key == mjx_hopper.cpu_key()
  monkeypatch.setattr(runtime, "_cpu_features", lambda: "avx2 avx512f fma sse4_2")
  assert mjx_hopper.cpu_key() != key
  assert key.split("-")[0] == (os.uname().machine or "cpu")


def test_another_cpu_compiles_afresh(tmp_path):
  first = compile_once(tmp_path)
  assert first["directory"] == str(tmp_path / mjx_hopper.cpu_key())
  assert first["misses"] >= 1 and first["hits"] == 0
  again = compile_once(tmp_path)
  assert again["hits"] >= 1 and again["misses"] == 0
  other = compile_once(tmp_path, "sse2 only")
  assert other["directory"] != first["directory"]
  assert other["misses"] >= 1 and other["hits"] == 0
  assert os.listdir(other["directory"])  # the other CPU's programs are kept apart


def test_a_trainer_of_another_config_is_traced_from_empty_caches():
  # trainers.build empties JAX's in-memory caches (which, once full, change how programs are
  # traced, and so their compile-cache keys) for a trainer other than the last one built, and
  # keeps them for the same one again (a resume: its programs are traced again quickly). A
  # jitted function of the process's own shows which: traced again after its caches emptied.
  traces = []

  def listen(event, secs, fun_name="", **_):
    if event == "/jax/core/compile/jaxpr_trace_duration" and fun_name == "doubled":
      traces.append(fun_name)
  jax.monitoring.register_event_duration_secs_listener(listen)

  @jax.jit
  def doubled(x):
    return 2 * x

  def traced_again():
    traces.clear()
    doubled(1.0)
    return len(traces)
  build = trainers.build.__wrapped__  # the product's, not the suite's memo (conftest)
  try:
    a, b = resolve(configs.tiny("d4pg")), resolve(configs.tiny("ddpg"))
    build(a)
    doubled(1.0)
    build(b)
    assert traced_again() == 1
    build(b)
    assert traced_again() == 0
    build(a)
    assert traced_again() == 1
  finally:
    jax.monitoring.unregister_event_duration_listener(listen)
