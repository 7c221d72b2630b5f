"""Checkpoint cost, for full TrainStates with 1M-transition replays of random numbers (the least
compressible case): how long `checkpoint.save` stops training (the copy to host memory), its
write on orbax's background thread, the manifest (file sizes and CRC32s), the restores and the
size on disk; each the median of --repeats saves and restores into fresh folders under --dir.

    python benchmarks/checkpoint_io.py                       # Hopper and Humanoid
    python benchmarks/checkpoint_io.py --envs Hopper --replay-size 100000
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
  figures = {k: [] for k in ("stall_s", "write_s", "manifest_s", "restore_s", "restore_agent_s",
                             "disk_mb")}
  for i in range(repeats):
    where = os.path.join(directory, f"{env_id}_{i}")
    mngr = checkpoint.manager(where)
    t0 = time.perf_counter()
    step = checkpoint.save(mngr, state, config)
    figures["stall_s"].append(time.perf_counter() - t0)
    mngr.wait_until_finished()
    figures["write_s"].append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    checkpoint.finish(mngr)
    figures["manifest_s"].append(time.perf_counter() - t0)
    folder = os.path.join(where, str(step))
    figures["disk_mb"].append(sum(os.path.getsize(os.path.join(root, name))
                                  for root, _, names in os.walk(folder) for name in names) / 1e6)
    fresh = checkpoint.manager(where)
    t0 = time.perf_counter()
    jax.block_until_ready(checkpoint.restore(fresh, step, state))
    figures["restore_s"].append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    jax.block_until_ready(checkpoint.restore_agent(fresh, step, state.agent))
    figures["restore_agent_s"].append(time.perf_counter() - t0)
    shutil.rmtree(where)
  return {"env": env_id, "replay_size": replay_size, "state_mb": total_bytes / 1e6,
          "replay_mb": replay_bytes / 1e6, **{k: statistics.median(v) for k, v in figures.items()}}


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
