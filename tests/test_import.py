"""Importing mjx_hopper changes nothing outside it; `mjx_hopper.setup` sets what it needs
process-wide, once."""

import json
import os
import subprocess
import sys

import jax
import pytest

import mjx_hopper
from mjx_hopper.process import runtime

CLEAN = {k: v for k, v in os.environ.items() if k not in (
    "MUJOCO_GL", "DISPLAY", "WAYLAND_DISPLAY", "XLA_FLAGS", "TF_CPP_MIN_LOG_LEVEL",
    "MJX_HOPPER_JAX_CACHE")}

# Imports every module of the package, and prints whether os.environ and JAX's config changed.
IMPORT_ALL = """
import importlib, json, os, pkgutil, sys
import gymnasium, jax  # what they set themselves (gymnasium: PYGAME_HIDE_SUPPORT_PROMPT) is theirs
environ, config = dict(os.environ), dict(jax.config.values)
import mjx_hopper, mjx_hopper.agents, mjx_hopper.envs
names = sorted({m.name for p in (mjx_hopper, mjx_hopper.agents, mjx_hopper.envs)
                for m in pkgutil.walk_packages(p.__path__, p.__name__ + ".")})
for name in names:
  try:
    importlib.import_module(name)
  except ModuleNotFoundError as error:  # an optional dependency (pybullet, onnx)
    if error.name.startswith("mjx_hopper"):
      raise
changed = sorted(k for k in set(environ) | set(os.environ) if environ.get(k) != os.environ.get(k))
print(json.dumps({"modules": len(names), "environ": changed,
                  "config": sorted(k for k, v in config.items() if jax.config.values[k] != v)}))
"""


def run(program: str, env: dict | None = None) -> str:
  done = subprocess.run([sys.executable, "-c", program], env=CLEAN if env is None else env,
                        capture_output=True, text=True, timeout=300)
  assert done.returncode == 0, done.stderr[-2000:]
  return done.stdout.strip().splitlines()[-1]


def test_importing_every_module_changes_no_environment_variable_and_no_jax_setting():
  out = json.loads(run(IMPORT_ALL))
  assert out["modules"] > 40
  assert out == {"modules": out["modules"], "environ": [], "config": []}


def test_importing_starts_no_jax():
  assert run("import sys, mjx_hopper; print('jax' in sys.modules)") == "False"


def test_a_run_imports_orbax_when_it_opens_checkpoints(tmp_path):
  # The CLI and the loop without orbax (about a second of a run's start): store.items imports
  # it where a checkpoint manager is made.
  assert run("import sys\nfrom mjx_hopper.faces import cli\nfrom mjx_hopper.run import loop\n"
             "print(any(m.split('.')[0] == 'orbax' for m in sys.modules))") == "False"
  assert run(f"import sys\nfrom mjx_hopper import store\nstore.manager({str(tmp_path)!r})\n"
             "print('orbax.checkpoint' in sys.modules)") == "True"


def test_the_settings_before_start_per_platform(monkeypatch):
  monkeypatch.setattr(runtime, "_shardy_crashes", lambda: False)
  choose = runtime.settings_before_start
  assert choose("Linux", {})["MUJOCO_GL"] == "egl"
  assert "MUJOCO_GL" not in choose("Linux", {"DISPLAY": ":0"})
  assert "MUJOCO_GL" not in choose("Linux", {"MUJOCO_GL": "osmesa"})
  no_ynn = "--xla_cpu_experimental_ynn_fusion_type="
  cores = f"--xla_force_host_platform_device_count={os.cpu_count()}"  # the default: one per core
  assert choose("Linux", {})["XLA_FLAGS"] == f"{cores} --xla_gpu_enable_triton_gemm=false {no_ynn}"
  assert choose("Linux", {"XLA_FLAGS": "--xla_gpu_enable_triton_gemm=true"})[
      "XLA_FLAGS"] == f"--xla_gpu_enable_triton_gemm=true {cores} {no_ynn}"
  assert choose("Darwin", {}) == {"XLA_FLAGS": f"{cores} {no_ynn}"}
  mine = f"--xla_force_host_platform_device_count=5 {no_ynn}dot"
  assert choose("Darwin", {"XLA_FLAGS": mine}) == {}  # a user's choices stay
  assert choose("Darwin", {"XLA_FLAGS": "--a --xla_force_host_platform_device_count=8"}, 3)[
      "XLA_FLAGS"] == f"--a --xla_force_host_platform_device_count=3 {no_ynn}"
  monkeypatch.setattr(runtime, "_shardy_crashes", lambda: True)  # GSPMD's warnings go
  assert choose("Darwin", {"XLA_FLAGS": mine}) == {"TF_CPP_MIN_LOG_LEVEL": "2"}
  assert choose("Darwin", {"XLA_FLAGS": mine, "TF_CPP_MIN_LOG_LEVEL": "0"}) == {}


SETUP = """
import json, os, jax, mjx_hopper
from mjx_hopper.faces import cli
first = mjx_hopper.setup()  # as loop.run calls it
environ = dict(os.environ)
again = mjx_hopper.setup(cpu_devices=cli._cpu_devices([]))  # as the CLI calls it
print(json.dumps({"same": first == again and environ == dict(os.environ), "dir": first,
                  "devices": len(jax.devices("cpu")), "gl": os.environ.get("MUJOCO_GL"),
                  "flags": os.environ["XLA_FLAGS"],
                  "cache": jax.config.jax_compilation_cache_dir,
                  "min_s": jax.config.jax_persistent_cache_min_compile_time_secs,
                  "collectives": jax.config.jax_cpu_collectives_implementation}))
"""


def test_setup_sets_the_process_once(tmp_path):
  out = json.loads(run(SETUP, {**CLEAN, "MJX_HOPPER_JAX_CACHE": str(tmp_path)}))
  # Python's first call and the CLI's, which keeps what the first set: a device per core, so
  # that `loop.run` trains as fast as `mjx-hopper train`.
  assert out["same"]
  assert out["dir"] == out["cache"] == str(tmp_path / mjx_hopper.cpu_key())
  assert out["devices"] == os.cpu_count() and out["min_s"] == 0.0
  assert out["collectives"] == "gloo"
  assert f"--xla_force_host_platform_device_count={os.cpu_count()}" in out["flags"]
  if sys.platform == "linux":
    assert out["gl"] == "egl" and "--xla_gpu_enable_triton_gemm=false" in out["flags"]
  assert "--xla_cpu_experimental_ynn_fusion_type=" in out["flags"]


def test_setup_after_jax_started_leaves_xla_flags_and_refuses_another_cpu_split():
  # This process's backends have started (conftest's setup, then the tests' programs).
  jax.devices()
  flags = os.environ.get("XLA_FLAGS")
  count = len(jax.devices("cpu"))
  assert mjx_hopper.setup(cpu_devices=count) == jax.config.jax_compilation_cache_dir
  assert os.environ.get("XLA_FLAGS") == flags
  with pytest.raises(ValueError, match=rf"cpu_devices={count + 1}, but JAX started its "
                     rf"backends before mjx_hopper.setup with {count} CPU device\(s\)"):
    mjx_hopper.setup(cpu_devices=count + 1)


@pytest.mark.parametrize("crashes, chosen, shardy", [
    (False, None, True), (True, None, False), (True, "true", True)])
def test_setup_avoids_shardy_where_it_crashes(monkeypatch, crashes, chosen, shardy):
  """jax 0.11's Shardy segfaults on our programs over several devices: setup switches such a
  jax to GSPMD, unless the user chose a partitioner."""
  before = jax.config.jax_use_shardy_partitioner
  monkeypatch.setattr(runtime, "_shardy_crashes", lambda: crashes)
  if chosen is None:
    monkeypatch.delenv("JAX_USE_SHARDY_PARTITIONER", raising=False)
  else:
    monkeypatch.setenv("JAX_USE_SHARDY_PARTITIONER", chosen)
  try:
    jax.config.update("jax_use_shardy_partitioner", True)
    mjx_hopper.setup()
    assert jax.config.jax_use_shardy_partitioner is shardy
  finally:
    jax.config.update("jax_use_shardy_partitioner", before)


@pytest.mark.slow  # a whole run in a fresh process
def test_a_mac_imports_the_envs_and_trains_on_cpu(tmp_path):
  program = ("import platform; platform.system = lambda: 'Darwin'\n"
             "import dataclasses\n"
             "from mjx_hopper.faces import notebook\n"
             "from mjx_hopper.run import loop\n"
             "cfg = notebook.tiny(loop.RunConfig(env='Hopper', agent='d4pg'))\n"
             f"cfg = dataclasses.replace(cfg, out_dir={str(tmp_path)!r}, total_env_steps=40)\n"
             "r = loop.run(cfg, progress=False, print_fn=lambda line: None)\n"
             "print(len(r.history))\n")
  # The tests' XLA flags and compile cache: the programs of test_train's tiny run, cached.
  env = {**CLEAN, "JAX_PLATFORMS": "cpu", "XLA_FLAGS": os.environ.get("XLA_FLAGS", ""),
         "MJX_HOPPER_JAX_CACHE": os.environ["MJX_HOPPER_JAX_CACHE"]}
  assert int(run(program, env)) >= 2


@pytest.mark.parametrize("version, crashes", [("0.9.2", False), ("0.11.2", True),
                                              ("0.12.0.1", False)])
def test_only_jax_0_11s_shardy_crashes(version, crashes):
  """jax 0.11's Shardy segfaulted on our programs over 2 devices; 0.9's and 0.12's compile and
  run them (a training chunk and the vector env's step), so they keep JAX's default."""
  assert runtime._shardy_crashes(version) is crashes
