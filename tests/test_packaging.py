"""The package as pip gets it: `python -m build` makes an sdist and, from it, a wheel that holds
the models, the pretrained policies and py.typed, and that installed away from the checkout
trains Hopper from its own console script. And pyproject's metadata: classifiers, one
repository address, comments without dates, machines or figures."""

import csv
import os
import re
import subprocess
import sys
import tomllib
import zipfile

import pytest

from configs import TINY_ARGS

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
  PROJECT = tomllib.load(f)["project"]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
  """The wheel `python -m build` makes from its sdist (offline: the test extra's setuptools)."""
  dist = tmp_path_factory.mktemp("dist")
  subprocess.run([sys.executable, "-m", "build", "--no-isolation", "--outdir", str(dist), ROOT],
                 check=True, capture_output=True)
  built = sorted(os.listdir(dist))
  assert [name.rsplit(".", 1)[-1] for name in built] == ["whl", "gz"], built
  return str(dist / built[0])


@pytest.mark.slow
def test_the_wheel_holds_the_package_and_its_data(wheel):
  names = zipfile.ZipFile(wheel).namelist()
  packages = {name.split("/")[0] for name in names}
  assert {p for p in packages if not p.endswith(".dist-info")} == {"mjx_hopper"}
  assert "mjx_hopper/py.typed" in names
  inside = [os.path.relpath(folder, ROOT) for folder, _, files in
            os.walk(os.path.join(ROOT, "mjx_hopper")) if "__init__.py" in files]
  assert {f"{p}/__init__.py" for p in inside} <= set(names)  # every sub-package (the floors)
  assert {n for n in names if n.startswith("mjx_hopper/envs/assets/")} == {
      f"mjx_hopper/envs/assets/{m}.xml" for m in ("hopper", "walker2d", "half_cheetah", "ant",
                                                   "humanoid")}
  shipped = sorted(f for f in os.listdir(os.path.join(ROOT, "mjx_hopper", "faces", "pretrained"))
                   if f.endswith(".npz"))
  assert sorted(n.rsplit("/", 1)[-1] for n in names
                if n.startswith("mjx_hopper/faces/pretrained/")) == shipped


@pytest.mark.slow
def test_the_installed_wheel_trains_hopper_away_from_the_checkout(wheel, tmp_path):
  site = tmp_path / "site"
  subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target",
                  str(site), wheel], check=True, capture_output=True)
  # Its dependencies from this environment; mjx_hopper from the wheel, ahead of the checkout's.
  env = dict(os.environ, PYTHONPATH=str(site))
  where = subprocess.run([sys.executable, "-c", "import mjx_hopper; print(mjx_hopper.__file__)"],
                         cwd=tmp_path, env=env, capture_output=True, text=True, check=True)
  assert where.stdout.startswith(str(site))
  done = subprocess.run([str(site / "bin" / "mjx-hopper"), *TINY_ARGS, "--total-env-steps",
                         "2000", "--eval-every", "1000", "--out-dir", "run"], cwd=tmp_path,
                        env=env, capture_output=True, text=True)
  assert done.returncode == 0, done.stderr[-3000:]
  with open(tmp_path / "run" / "log.csv") as f:
    assert max(int(row["env_steps"]) for row in csv.DictReader(f)) >= 2000


def test_pyproject_says_what_pypi_shows():
  assert PROJECT["requires-python"] == ">=3.11"
  versions = [c.rsplit(" ", 1)[-1] for c in PROJECT["classifiers"]
              if c.startswith("Programming Language :: Python :: 3.")]
  assert versions == ["3.11", "3.12"]
  assert "Typing :: Typed" in PROJECT["classifiers"]
  repository = PROJECT["urls"]["Repository"]
  assert set(PROJECT["urls"]) == {"Repository", "Documentation", "Changelog"}
  assert all(url.startswith(repository + "/") for k, url in PROJECT["urls"].items()
             if k != "Repository")
  with open(os.path.join(ROOT, "notebooks", "robolympics.ipynb")) as f:
    assert f'REPO_URL = \\"{repository}\\"' in f.read()  # one address for both


def test_pyprojects_comments_carry_no_dates_machines_or_figures():
  with open(os.path.join(ROOT, "pyproject.toml")) as f:
    comments = [line.split("#", 1)[1] for line in f if "#" in line]
  found = [c for c in comments if re.search(
      r"\d{4}-\d\d-\d\d|\b[HAV]100\b|\bH200\b|\bcores?\b|\d+(\.\d+)?\s?(%|x\b|×|s\b|min\b)", c)]
  assert not found
