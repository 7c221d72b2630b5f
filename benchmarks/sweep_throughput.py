"""Sweep throughput: S members in one compiled program against S single runs one after another.

    python benchmarks/sweep_throughput.py                                  # 2-core CPU

Each S in a fresh process: S seeds of D4PG on Hopper learning from the first iteration, timed
over --chunks chunks after a warm-up chunk (report.py sets their env steps/s against S = 1 on
the fewest devices). With --gpus 1,2 each S runs on the first GPU, then on the first two.
Compile is the chunk's, trace excluded; memory the busiest GPU's peak in use, or the process's
peak RSS where the devices do not report it.
"""

from __future__ import annotations

import dataclasses
import os
import resource
import sys

import common


def measure(args) -> dict:
  """One sweep of args.members members: compile time, rates and memory."""
  import mjx_hopper
  mjx_hopper.setup()  # before the package loads (and anything compiles)
  import jax

  from mjx_hopper.run import trainers
  from mjx_hopper.settings import config, flags
  from mjx_hopper.settings.training import TrainConfig

  cfg = config.RunConfig(
      env=args.env, agent=args.agent, agent_defaults=args.preset,
      agent_overrides=flags.overrides(args.set),
      train=TrainConfig(num_envs=args.num_envs, unroll_length=args.unroll_length,
                        batch_size=args.batch_size, replay_ratio=args.replay_ratio,
                        replay_size=args.replay_size, min_replay=0,
                        iterations_per_chunk=args.chunk),
      seeds=tuple(range(args.members)) if args.members > 1 else ())
  # Learning from the first iteration.
  cfg = dataclasses.replace(cfg, train=dataclasses.replace(
      cfg.train, min_replay=cfg.train.steps_per_iteration))
  trainer = trainers.build(cfg)
  timed = common.Timed(trainer.chunk, trainers.init(cfg, trainer, cfg.member_settings()),
                       trainer=trainer)
  seconds = timed(args.chunks)
  per_chunk = args.members * cfg.train.steps_per_iteration * args.chunk * args.chunks
  updates = args.members * cfg.train.updates_per_iteration * args.chunk * args.chunks
  device = jax.local_devices()[0]
  stats = [d.memory_stats() for d in jax.local_devices()] if device.platform == "gpu" else []
  memory = (max(s["peak_bytes_in_use"] for s in stats) if stats and all(stats)
            else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024)
  return {"members": args.members, "compile_s": timed.compile_s, "memory_gb": memory / 1e9,
          "env_steps_per_s": per_chunk / seconds, "updates_per_s": updates / seconds,
          "platform": device.platform, "devices": len(jax.local_devices())}


def main() -> None:
  p = common.parser(__doc__)
  p.add_argument("--members", default="1,4,16,64", help="comma-separated sweep sizes")
  p.add_argument("--env", default="Hopper")
  p.add_argument("--agent", default="d4pg")
  p.add_argument("--preset", default="cpu")
  p.add_argument("--num-envs", type=int, default=128, help="envs per member")
  p.add_argument("--unroll-length", type=int, default=4)
  p.add_argument("--batch-size", type=int, default=256, help="per member")
  p.add_argument("--replay-ratio", type=float, default=4.0)
  p.add_argument("--replay-size", type=int, default=100_000, help="transitions per member")
  p.add_argument("--chunk", type=int, default=5, help="iterations per chunk")
  p.add_argument("--chunks", type=int, default=3, help="timed chunks")
  p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                 help="an agent setting, such as compute_dtype=bfloat16 (repeatable)")
  p.add_argument("--cpu-devices", type=int, default=os.cpu_count() or 1)
  p.add_argument("--gpus", help="comma-separated GPU counts: every sweep size on the first N "
                 "GPUs, for each N (default: on every visible GPU)")
  p.add_argument("--label", default="cpu",
                 help="results: benchmarks/results/sweep_throughput_LABEL.json")
  args = common.parse(p, measure)  # a worker: one sweep size in a process of its own
  rows = []
  gpu_counts = [int(n) for n in args.gpus.split(",")] if args.gpus else [None]
  for gpus in gpu_counts:
    for members in [int(m) for m in args.members.split(",")]:
      row = common.worker(__file__, dict(vars(args), members=members),
                          gpus or args.cpu_devices, gpus is not None)
      if row is None:  # the sizes before it are still written
        break
      rows.append(row)
      print(f"  S = {members} on {row['devices']} device(s): {row['env_steps_per_s']:,.0f} env "
            "steps/s", file=sys.stderr, flush=True)
  common.write_results(f"sweep_throughput_{args.label}", {
      "settings": {k: v for k, v in vars(args).items() if k != "worker"}, "rows": rows})


if __name__ == "__main__":
  main()
