"""What `import mjx_hopper` does: it starts no JAX, and sets MuJoCo's GL backend only on Linux
without a display, and only when unset."""

import os
import subprocess
import sys

import mjx_hopper

CLEAN = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY",
                                                          "WAYLAND_DISPLAY", "XLA_FLAGS")}


def test_the_gl_backend_is_chosen_per_platform():
  choose = mjx_hopper._settings_before_start
  assert choose("Linux", {})["MUJOCO_GL"] == "egl"
  assert "MUJOCO_GL" not in choose("Linux", {"DISPLAY": ":0"})
  assert "MUJOCO_GL" not in choose("Linux", {"MUJOCO_GL": "osmesa"})
  assert choose("Darwin", {}) == {} and choose("Windows", {}) == {}
  assert "xla_gpu_enable_triton_gemm=true" in choose(
      "Linux", {"XLA_FLAGS": "--xla_gpu_enable_triton_gemm=true"}).get(
          "XLA_FLAGS", "--xla_gpu_enable_triton_gemm=true")


def test_importing_starts_no_jax_and_a_mac_gets_no_settings():
  program = ("import platform, sys, os; platform.system = lambda: 'Darwin'; import mjx_hopper; "
             "print('jax' in sys.modules, os.environ.get('MUJOCO_GL'), "
             "os.environ.get('XLA_FLAGS'))")
  out = subprocess.run([sys.executable, "-c", program], env=CLEAN, capture_output=True,
                       text=True, check=True).stdout.split()
  assert out == ["False", "None", "None"]


def test_a_mac_imports_the_envs_and_trains_on_cpu(tmp_path):
  program = ("import platform; platform.system = lambda: 'Darwin'\n"
             "import dataclasses\n"
             "from mjx_hopper import loop, notebook\n"
             "cfg = notebook.tiny(loop.RunConfig(env='Hopper', agent='d4pg'))\n"
             f"cfg = dataclasses.replace(cfg, out_dir={str(tmp_path)!r}, total_env_steps=40)\n"
             "r = loop.run(cfg, progress=False, print_fn=lambda line: None)\n"
             "print(len(r.history))\n")
  # The tests' XLA flags and compile cache: the programs of test_train's tiny run, cached.
  env = {**CLEAN, "JAX_PLATFORMS": "cpu", "XLA_FLAGS": os.environ.get("XLA_FLAGS", "")}
  done = subprocess.run([sys.executable, "-c", program], env=env, capture_output=True,
                        text=True, timeout=600)
  assert done.returncode == 0, done.stderr[-2000:]
  assert int(done.stdout.split()[-1]) >= 2
