"""Checkpoint cost: how long a save stops training, how long the write takes, how long a restore
takes, and the size on disk, for full TrainStates with 1M-transition replays.

    python benchmarks/checkpoint_io.py                       # Hopper and Humanoid
    python benchmarks/checkpoint_io.py --envs Hopper --replay-size 100000

The replay is filled with random normal numbers (what a full buffer holds, at its least
compressible), the rest is the trainer's initial state. "stall" is the time `checkpoint.save`
blocks the caller (the copy to host memory); "write" runs on orbax's background thread while
training would go on; "manifest" lists the finished step's files with sizes and CRC32s (done
before the next save). Each figure is the median of --repeats saves and restores into a fresh
directory under --dir.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import statistics
import tempfile
import time


def measure(env_id: str, replay_size: int, directory: str, repeats: int) -> dict:
  import jax

  from mjx_hopper import checkpoint, loop, train

  cfg = loop.RunConfig(env=env_id, train=train.TrainConfig(replay_size=replay_size))
  trainer = loop.build(cfg)
  state = trainer.init(jax.random.PRNGKey(0))
  steps = state.replay.steps
  noise = jax.jit(lambda k: jax.tree.map(
      lambda x: jax.random.normal(k, x.shape, x.dtype), steps),
      out_shardings=jax.tree.map(lambda x: x.sharding, steps))
  state = state._replace(replay=state.replay._replace(steps=noise(jax.random.PRNGKey(1))))
  jax.block_until_ready(state)
  replay_bytes = sum(x.nbytes for x in jax.tree.leaves(state.replay))
  total_bytes = sum(x.nbytes for x in jax.tree.leaves(state))
  config = cfg.to_json()
  stall, write, manifest, restore, restore_agent, size = [], [], [], [], [], []
  for i in range(repeats):
    where = os.path.join(directory, f"{env_id}_{i}")
    mngr = checkpoint.manager(where)
    t0 = time.perf_counter()
    step = checkpoint.save(mngr, state, config)
    stall.append(time.perf_counter() - t0)
    mngr.wait_until_finished()
    write.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    checkpoint.finish(mngr)
    manifest.append(time.perf_counter() - t0)
    size.append(sum(os.path.getsize(os.path.join(root, name))
                    for root, _, names in os.walk(os.path.join(where, str(step)))
                    for name in names))
    fresh = checkpoint.manager(where)
    t0 = time.perf_counter()
    jax.block_until_ready(checkpoint.restore(fresh, step, state))
    restore.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    jax.block_until_ready(checkpoint.restore_agent(fresh, step, state.agent))
    restore_agent.append(time.perf_counter() - t0)
    shutil.rmtree(where)
  return {"env": env_id, "replay_size": replay_size, "state_mb": total_bytes / 1e6,
          "replay_mb": replay_bytes / 1e6, "disk_mb": statistics.median(size) / 1e6,
          "stall_s": statistics.median(stall), "write_s": statistics.median(write),
          "manifest_s": statistics.median(manifest), "restore_s": statistics.median(restore),
          "restore_agent_s": statistics.median(restore_agent)}


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--envs", default="Hopper,Humanoid")
  parser.add_argument("--replay-size", type=int, default=1_000_000)
  parser.add_argument("--repeats", type=int, default=3)
  parser.add_argument("--dir", default=None, help="where to write (default: a temporary folder)")
  args = parser.parse_args()
  directory = args.dir or tempfile.mkdtemp(prefix="checkpoint_io_")
  rows = [measure(e, args.replay_size, directory, args.repeats) for e in args.envs.split(",")]
  print(f"# checkpoint save/restore, {time.strftime('%Y-%m-%d')}, {platform.node()}, "
        f"{os.cpu_count()} CPUs, writing to {directory}\n")
  print("| env | replay | state in memory (MB) | on disk (MB) | save stalls training (s) "
        "| write (s) | manifest (s) | restore all (s) | restore agent only (s) |")
  print("|---|---|---|---|---|---|---|---|---|")
  for r in rows:
    print(f"| {r['env']} | {r['replay_size']:,} | {r['state_mb']:,.0f} | {r['disk_mb']:,.0f} "
          f"| {r['stall_s']:.2f} | {r['write_s']:.2f} | {r['manifest_s']:.2f} "
          f"| {r['restore_s']:.2f} | {r['restore_agent_s']:.3f} |")


if __name__ == "__main__":
  main()
