"""The run folder's one reader: a member is named by its index in the sweep everywhere (eval,
export, extract), and a checkpoint that holds some members only is read by their indices."""

import dataclasses

import jax
import numpy as np
import pytest

from mjx_hopper import store
from mjx_hopper.faces import cli, export
from mjx_hopper.run import checkpoints, trainers
from mjx_hopper.settings.plan import resolve
from mjx_hopper.settings import config
from mjx_hopper.store.run_folder import RunFolder, Saved, check_processes
from configs import TINY


@pytest.fixture(scope="module")
def partial(tmp_path_factory):
  """A checkpoint holding members 2 and 3 of a 4-member sweep, at positions 0 and 1 (its config
  item names the members it holds); member 3 has the best evaluation."""
  cfg = dataclasses.replace(TINY, seeds=(0, 1, 2, 3),
                            out_dir=str(tmp_path_factory.mktemp("partial")))
  folder = RunFolder(cfg.out_dir)
  plan = resolve(cfg, 2)
  trainer = trainers.build(plan)
  state = trainers.init(plan, trainer, plan.members[2:])
  record = {"best_return": [1.0, 5.0], "best_env_steps": [40, 40]}
  mngr = store.manager(folder.checkpoints)
  store.save(mngr, state, {**cfg.saved([2, 3]), "record": record})
  store.wait_and_record(mngr)
  return folder.checkpoints, state


def test_a_member_is_its_index_not_its_position(partial):
  directory, state = partial
  saved = Saved.read(store.manager(directory), 0)
  assert saved.indices == [2, 3]
  assert [m["seed"] for m in saved.member_settings()] == [2, 3]
  assert [saved.position(m) for m in (2, 3, "best")] == [0, 1, 1]
  for index, position in ((2, 0), (3, 1), ("best", 1)):
    agent = checkpoints.load_member(directory, index, which="latest", print_fn=lambda _: None).agent
    jax.tree.map(np.testing.assert_array_equal, agent,
                 jax.tree.map(lambda x: x[position], jax.device_get(state.agent)))


@pytest.mark.parametrize("member, message", [
    (0, r"member 0 is not in .*partial\d*/checkpoints: it holds members \[2, 3\]"),
    (None, r"partial\d*/checkpoints holds a sweep of 2 members: give a member's index"),
    ("two", "member takes a member's index or 'best', got 'two'")])
def test_a_member_the_checkpoint_lacks_is_refused_in_one_line(partial, member, message,
                                                               tmp_path):
  directory, _ = partial
  with pytest.raises(store.ConfigMismatch, match=message):
    checkpoints.load_member(directory, member, print_fn=lambda _: None)
  with pytest.raises(ValueError, match=message):
    export.export_checkpoint(directory, str(tmp_path / "policy.npz"), member=member)
  assert not (tmp_path / "policy.npz").exists()


def test_the_cli_takes_a_members_index(partial, capsys):
  directory, _ = partial
  with pytest.raises(SystemExit, match=r"mjx-hopper eval: member 0 is not in .*: it holds "
                     r"members \[2, 3\]"):
    cli.main(["--cpu-devices", "2", "eval", "--checkpoint", directory, "--member", "0"])
  with pytest.raises(SystemExit, match=r"mjx-hopper extract: member 1 is not in .*: it holds "
                     r"members \[2, 3\]"):
    cli.main(["--cpu-devices", "2", "extract", "--checkpoint", directory, "--member", "1",
              "--out", "unused"])


def test_config_json_is_the_config_item(tmp_path):
  cfg = dataclasses.replace(TINY, out_dir=str(tmp_path))
  folder = RunFolder(cfg.out_dir)
  assert folder.path == str(tmp_path) and folder.log == str(tmp_path / "log.csv")
  folder.write_config(cfg.saved([0]))
  assert config.load(str(tmp_path / "config.json")).to_json() == cfg.to_json()
  assert folder.grid() == {}


def test_a_run_over_processes_resumes_on_as_many(tmp_path):
  cfg = dataclasses.replace(TINY, seeds=(0, 1), out_dir=str(tmp_path))
  assert "processes" not in cfg.saved([0, 1])
  plan = resolve(cfg, 2)
  trainer = trainers.build(plan)
  mngr = store.manager(RunFolder(cfg.out_dir).checkpoints)
  check_processes(mngr, 2)  # nothing saved yet: any number
  store.save(mngr, trainers.init(plan, trainer), cfg.saved([0, 1], 2))
  store.wait_and_record(mngr)
  check_processes(mngr, 2)
  saved = Saved.read(mngr, mngr.latest_step())  # eval, export and extract read it as any
  assert saved.item["processes"] == 2 and saved.config.to_json() == cfg.to_json()
  with pytest.raises(store.ConfigMismatch, match=r"saved by a run over 2 process\(es\), and this "
                     r"run has 1: resume it on 2; nothing was written"):
    check_processes(mngr, 1)
