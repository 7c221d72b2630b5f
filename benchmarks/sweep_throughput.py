"""Sweep throughput: S members in one compiled program against S single runs one after another.

    python benchmarks/sweep_throughput.py                                  # 2-core CPU

Each S in a fresh process: S seeds of D4PG on Hopper learning from the first iteration, timed
over --chunks chunks after a warm-up chunk; "x sequential" is their env steps/s over that of
S = 1 on the fewest devices. With --gpus 1,2 each S runs on the first GPU, then on the first
two, so the 2-GPU rows' "x sequential" is over one member on one GPU.
Compile is the chunk's, trace excluded; memory the busiest GPU's peak in use, or the process's
peak RSS where the devices do not report it.
BENCHMARKS.md, "Sweeps", has the GPU's command.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import resource
import sys

import common


def measure(args) -> dict:
  """One sweep of args.members members: compile time, rates and memory."""
  import jax

  from mjx_hopper import cli, loop, train

  cfg = loop.RunConfig(
      env=args.env, agent=args.agent, preset=args.preset,
      agent_overrides=cli._overrides(args.set),
      train=train.TrainConfig(num_envs=args.num_envs, unroll_length=args.unroll_length,
                              batch_size=args.batch_size, replay_ratio=args.replay_ratio,
                              replay_size=args.replay_size, min_replay=0,
                              iterations_per_chunk=args.chunk),
      seeds=tuple(range(args.members)) if args.members > 1 else ())
  # Learning from the first iteration, or with --collect-only never (the replay never fills):
  # the env steps, the policy's actions and the replay inserts alone.
  cfg = dataclasses.replace(cfg, train=dataclasses.replace(
      cfg.train, min_replay=args.replay_size if args.collect_only
      else cfg.train.steps_per_iteration))
  trainer = loop.build(cfg)
  timed = common.Timed(trainer.train_chunk, loop.init(cfg, trainer, cfg.members()))
  seconds = timed(args.chunks)
  per_chunk = args.members * cfg.train.steps_per_iteration * args.chunk * args.chunks
  updates = (0 if args.collect_only else
             args.members * cfg.train.updates_per_iteration * args.chunk * args.chunks)
  device = jax.local_devices()[0]
  stats = [d.memory_stats() for d in jax.local_devices()] if device.platform == "gpu" else []
  memory = (max(s["peak_bytes_in_use"] for s in stats) if stats and all(stats)
            else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024)
  return {"members": args.members, "compile_s": timed.compile_s, "memory_gb": memory / 1e9,
          "env_steps_per_s": per_chunk / seconds, "updates_per_s": updates / seconds,
          "platform": device.platform, "devices": len(jax.local_devices())}


def main() -> None:
  p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
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
  p.add_argument("--collect-only", action="store_true",
                 help="learning off: time the env steps, actions and replay inserts alone")
  p.add_argument("--cpu-devices", type=int, default=os.cpu_count() or 1)
  p.add_argument("--gpus", help="comma-separated GPU counts: every sweep size on the first N "
                 "GPUs, for each N (default: on every visible GPU)")
  p.add_argument("--label", default="cpu",
                 help="results: benchmarks/results/sweep_throughput_LABEL.json")
  p.add_argument("--worker", help=argparse.SUPPRESS)  # one sweep size's arguments, as JSON
  args = p.parse_args()
  if args.worker:
    import mjx_hopper  # its own imports only: JAX starts in measure
    mjx_hopper.use_compile_cache()
    print(json.dumps(measure(argparse.Namespace(**json.loads(args.worker)))))
    return
  rows = []
  gpu_counts = [int(n) for n in args.gpus.split(",")] if args.gpus else [None]
  for gpus in gpu_counts:
    for members in [int(m) for m in args.members.split(",")]:
      row = common.worker(__file__, dict(vars(args), members=members),
                          gpus or args.cpu_devices, gpus is not None)
      if row is None:  # the sizes before it still make a table
        break
      rows.append(row)
      print(f"  S = {members} on {row['devices']} device(s): {row['env_steps_per_s']:,.0f} env "
            "steps/s", file=sys.stderr, flush=True)
  singles = [r for r in rows if r["members"] == 1]
  base = min(singles, key=lambda r: r["devices"])["env_steps_per_s"] if singles else None
  lines = common.table(
      ["devices", "members", "compile (s)", "env steps/s", "updates/s", "memory (GB)",
       "x sequential"],
      [[r["devices"], r["members"], f"{r['compile_s']:.1f}", f"{r['env_steps_per_s']:,.0f}",
        f"{r['updates_per_s']:,.0f}", f"{r['memory_gb']:.2f}",
        f"{r['env_steps_per_s'] / base:.2f}" if base else "-"] for r in rows])
  print(f"{platform.node()}, {rows[0]['platform'] if rows else ''} devices, {args.env} "
        f"{args.agent} ({args.preset}{', ' + ', '.join(args.set) if args.set else ''}), "
        f"{args.num_envs} envs and batch {args.batch_size} per member"
        f"{', collect only (learning off)' if args.collect_only else ''}\n{lines}")
  common.write_results(f"sweep_throughput_{args.label}", {
      "settings": {k: v for k, v in vars(args).items() if k != "worker"}, "rows": rows})


if __name__ == "__main__":
  main()
