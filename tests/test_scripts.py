"""The installers. The setup scripts, run in a scratch copy against a stand-in Python and apt: a
Python older than the floor is one line before anything is downloaded, and a Python without venv
gets Debian's package for it, with the EGL packages. The notebook's install cell runs where there
is no apt, saying what it skipped."""

import json
import os
import shutil
import subprocess
import sys
from importlib.metadata import version

import pytest

SCRIPTS = os.path.join(os.path.dirname(__file__), "..", "scripts")

# A stand-in interpreter: answers the floor check (OLD=1: too old), -V, the venv probe (no
# ensurepip, as a stock Debian Python) and the version; anything else (the venv) fails.
PYTHON = """#!/usr/bin/env bash
case "$*" in
  *"version_info < (3, 11)"*) exit "$OLD" ;;
  -V) echo "Python 3.10.12" ;;
  *ensurepip*) exit 1 ;;
  *print*) echo 3.11 ;;
  *) echo "python $*" >> "$LOG"; exit 3 ;;
esac
"""
RECORDER = """#!/usr/bin/env bash
echo "$(basename "$0") $*" >> "$LOG"
"""


def run_script(tmp_path, name: str, old: bool):
  """`scripts/NAME` run from a copy of the scripts, with the stand-ins first on PATH and every
  command they were asked to do logged; (the completed process, the log's lines)."""
  shutil.copytree(SCRIPTS, tmp_path / "scripts")
  bin_dir = tmp_path / "bin"
  bin_dir.mkdir()
  for tool, text in (("python-stand-in", PYTHON), ("apt-get", RECORDER), ("sudo", RECORDER),
                     ("nvidia-smi", "#!/bin/sh\nexit 1\n"),
                     ("dpkg-query", "#!/bin/sh\nexit 1\n")):  # nothing is installed
    (bin_dir / tool).write_text(text)
    (bin_dir / tool).chmod(0o755)
  log = tmp_path / "log"
  env = dict(os.environ, PATH=f"{bin_dir}:{os.environ['PATH']}", PYTHON="python-stand-in",
             OLD="1" if old else "0", LOG=str(log))
  done = subprocess.run(["bash", str(tmp_path / "scripts" / name)], env=env, capture_output=True,
                        text=True)
  return done, log.read_text().splitlines() if log.exists() else []


@pytest.mark.parametrize("name", ["main.sh", "setup.sh", "test.sh"])
def test_a_too_old_python_is_one_line_before_any_download(tmp_path, name):
  done, log = run_script(tmp_path, name, old=True)
  assert done.returncode == 1
  assert done.stderr.splitlines() == [
      "mjx_hopper needs Python >= 3.11 (JAX's floor), and python-stand-in is Python 3.10.12: "
      "install a newer Python and run again with PYTHON=python3.11 (or newer)"]
  assert log == [] and not (tmp_path / ".venv").exists()


def test_a_python_without_venv_gets_debians_package(tmp_path):
  done, log = run_script(tmp_path, "setup.sh", old=False)
  assert done.returncode == 3  # the stand-in refuses to make the venv
  packages = "libegl1 libegl-mesa0 libgl1-mesa-dri libgles2 python3.11-venv"
  assert f"installing Debian packages: {packages}" in done.stdout
  apt = [line.removeprefix("sudo ") for line in log if "apt-get" in line]
  assert apt[-1] == f"apt-get install -y -qq {packages}"
  assert log[-1] == "python -m venv .venv"


def test_the_notebooks_install_cell_runs_without_apt(tmp_path):
  with open(os.path.join(SCRIPTS, "..", "notebooks", "robolympics.ipynb")) as f:
    cell = next("".join(c["source"]) for c in json.load(f)["cells"]
                if c["cell_type"] == "code" and "\nREPO_URL = " in "".join(c["source"]))
  env = dict(os.environ, PATH=str(tmp_path), MJX_HOPPER_SHORT="1")  # no apt, no dpkg
  done = subprocess.run([sys.executable, "-c", cell], env=env, capture_output=True, text=True,
                        cwd=tmp_path)
  assert done.returncode == 0, done.stderr
  lines = done.stdout.splitlines()
  assert lines[:2] == ["no apt here: skipped Mesa's EGL packages (for videos, install your "
                       "system's EGL)", "to install: nothing"]
  assert lines[2] == f"JAX {version('jax')}, as it was installed"


def test_the_floor_job_pins_each_runtime_dependency_to_its_lower_bound(tmp_path):
  import tomllib
  root = os.path.join(SCRIPTS, "..")
  with open(os.path.join(root, "pyproject.toml"), "rb") as f:
    dependencies = tomllib.load(f)["project"]["dependencies"]
  done = subprocess.run([sys.executable, os.path.join(root, ".ci", "floor_constraints.py"),
                         os.path.join(root, "pyproject.toml")], capture_output=True, text=True)
  assert done.returncode == 0, done.stderr
  pins = dict(line.split("==") for line in done.stdout.split())
  assert len(pins) == len(dependencies) and pins["jax"] == "0.9.2"
  (tmp_path / "pyproject.toml").write_text('[project]\ndependencies = ["jax<0.13"]\n')
  done = subprocess.run([sys.executable, os.path.join(root, ".ci", "floor_constraints.py"),
                         str(tmp_path / "pyproject.toml")], capture_output=True, text=True)
  assert done.returncode == 1
  assert done.stderr == ("'jax<0.13' in pyproject.toml has no lower bound (>=X) to pin the "
                         "floor job to\n")
