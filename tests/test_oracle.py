"""The recorded PyBullet data in tests/oracle/ against PyBullet itself, where PyBullet imports
(the oracle extra, Python 3.11): recorded again, every array is what the file holds."""

import json

import numpy as np
import pytest

from conftest import ORACLE, ROBOTS, oracle

pytest.importorskip("pybullet", reason="PyBullet is not installed here (pip install -e "
                    "'.[oracle]' on Python 3.11), so tests/oracle/ is not checked against it")
import record_oracle  # noqa: E402  (imports pybullet_oracle, which needs PyBullet)


def check_same(name: str, fresh: dict) -> None:
  recorded = oracle(name)
  assert sorted(fresh) == sorted(recorded), name
  for key, value in fresh.items():
    if value.dtype.kind in "UOb":
      np.testing.assert_array_equal(value, recorded[key], err_msg=f"{name} {key}")
    else:  # float32 fields were stored as float32: compare at their precision
      np.testing.assert_allclose(value.astype(recorded[key].dtype), recorded[key], rtol=1e-6,
                                 atol=1e-6, err_msg=f"{name} {key}")


def test_the_data_was_recorded_with_the_installed_pybullet():
  from importlib.metadata import version
  with np.load(f"{ORACLE}/Hopper.npz") as data:
    meta = json.loads(str(data["meta"]))
  assert meta["pybullet"] == version("pybullet")
  assert meta["command"].startswith("python tests/record_oracle.py")


@pytest.mark.parametrize("robot", ROBOTS)
def test_recorded_data_is_what_pybullet_computes(robot):
  check_same(robot, record_oracle.record(robot))


def test_recorded_euler_angles_are_pybullets():
  check_same("euler", record_oracle.euler_angles())
