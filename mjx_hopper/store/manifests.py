"""Beside the steps, a manifest of each finished step's files (sizes and CRC32s), so that a
damaged step can be told apart file by file; `wait_and_record` writes them once a save has
finished."""

from __future__ import annotations

import json
import os
import zlib
from typing import TYPE_CHECKING

import jax

from mjx_hopper.store.failures import failed

if TYPE_CHECKING:  # orbax is imported where a checkpoint is first opened (store.items)
  import orbax.checkpoint as ocp


MANIFESTS = "manifests"  # beside the steps: the files of each finished step, with sizes and CRCs


def files(step_dir: str) -> dict[str, tuple[int, int]]:
  """{relative path: (size, crc32)} of every file under `step_dir`."""
  out = {}
  for root, _, names in os.walk(step_dir):
    for name in names:
      path = os.path.join(root, name)
      with open(path, "rb") as f:
        out[os.path.relpath(path, step_dir)] = (os.path.getsize(path), zlib.crc32(f.read()))
  return out


def wait_and_record(mngr: ocp.CheckpointManager) -> None:
  """Waits for the save in flight, then records the files of every finished step that has no
  manifest yet (and drops the manifests of steps that are gone), so that a damaged step can be
  told apart file by file later. A save that failed is a SaveFailed (see `failed`)."""
  try:
    mngr.wait_until_finished()
    if jax.process_index() == 0:  # over processes, process 0 writes the files beside the steps
      write_manifests(mngr)
  except Exception as error:  # noqa: BLE001 - orbax and tensorstore wrap OSErrors in their own
    raise failed(mngr, None, error) from None


def write_manifests(mngr: ocp.CheckpointManager) -> None:
  """A manifest for each step that has none, written whole or not at all, and none for a step
  that is gone."""
  folder = os.path.join(mngr.directory, MANIFESTS)
  steps = {str(step) for step in mngr.all_steps()}
  if not steps and not os.path.isdir(folder):
    return
  os.makedirs(folder, exist_ok=True)
  for name in os.listdir(folder):
    if name.removesuffix(".json") not in steps:
      os.remove(os.path.join(folder, name))
  for step in steps - {n.removesuffix(".json") for n in os.listdir(folder)}:
    path = os.path.join(folder, f"{step}.json")
    with open(path + ".tmp", "w") as f:
      json.dump(files(os.path.join(mngr.directory, step)), f)
    os.replace(path + ".tmp", path)


def damage(mngr: ocp.CheckpointManager, step: int) -> list[str]:
  """How `step`'s files differ from its manifest: one line per missing, truncated or changed
  file (empty when they match, or when the step has no manifest)."""
  path = os.path.join(mngr.directory, MANIFESTS, f"{step}.json")
  if not os.path.exists(path):
    return []
  with open(path) as f:
    saved = json.load(f)
  step_dir = os.path.join(mngr.directory, str(step))
  now = files(step_dir)
  out = []
  for name, (size, crc) in sorted(saved.items()):
    file = os.path.join(step_dir, name)
    if name not in now:
      out.append(f"{file} is missing")
    elif now[name][0] != size:
      out.append(f"{file} has {now[name][0]:,} bytes, {size:,} when saved")
    elif now[name][1] != crc:
      out.append(f"{file} has changed since it was saved (CRC32)")
  return out
