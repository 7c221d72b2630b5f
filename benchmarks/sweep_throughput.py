"""Sweep throughput: S members in one compiled program against S single runs one after another.

    python benchmarks/sweep_throughput.py                                  # 2-core CPU
    python benchmarks/sweep_throughput.py --preset gpu --num-envs 512 --batch-size 1024 \\
        --members 1,4,16,64 --out benchmarks/results/sweep_throughput_h100.json   # one GPU

Each S runs in a fresh process (its own compile and memory): a sweep of S seeds of D4PG on
Hopper, learning from the first iteration (min_replay = one iteration's steps), timed over
`--chunks` chunks after a warm-up chunk. S single runs one after another run at the S = 1
rate, so "x sequential" is the sweep's combined env steps/s over the single run's. Compile is
XLA's compile of the training chunk (trace excluded); memory is the GPU's peak bytes in use,
or on a CPU the process's peak resident size.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import resource
import subprocess
import sys
import time


def run_sweep(args):
  """Builds the sweep of args.members members, compiles its chunk, runs a warm-up chunk and
  times args.chunks more: (its RunConfig, the compiled chunk, the state after them, the compile's
  seconds, the timed chunks' seconds)."""
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
  state = loop.init(cfg, trainer, cfg.members())
  lowered = trainer.train_chunk.lower(state)
  start = time.perf_counter()
  compiled = lowered.compile()
  compile_s = time.perf_counter() - start
  state, metrics = compiled(state)
  jax.block_until_ready(metrics)
  start = time.perf_counter()
  for _ in range(args.chunks):
    state, metrics = compiled(state)
  jax.block_until_ready(metrics)
  return cfg, compiled, state, compile_s, time.perf_counter() - start


def measure(args) -> dict:
  """One sweep of args.members members: compile time, rates and memory."""
  import jax

  cfg, _, _, compile_s, seconds = run_sweep(args)
  per_chunk = args.members * cfg.train.steps_per_iteration * args.chunk * args.chunks
  updates = (0 if args.collect_only else
             args.members * cfg.train.updates_per_iteration * args.chunk * args.chunks)
  device = jax.local_devices()[0]
  stats = device.memory_stats() if device.platform == "gpu" else None
  memory = (stats["peak_bytes_in_use"] if stats
            else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024)
  return {"members": args.members, "compile_s": compile_s, "env_steps_per_s": per_chunk / seconds,
          "updates_per_s": updates / seconds, "memory_gb": memory / 1e9,
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
  p.add_argument("--out", default="benchmarks/results/sweep_throughput_cpu.json")
  p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
  args = p.parse_args()
  import mjx_hopper  # its own imports only: JAX starts in measure
  if args.worker:
    args.members = int(args.members)
    mjx_hopper.use_compile_cache()
    print(json.dumps(measure(args)))
    return
  env = dict(os.environ, XLA_FLAGS=mjx_hopper.xla_flags_with_cpu_devices(args.cpu_devices))
  rows = []
  settings = [f"--{name.replace('_', '-')}={value}" for name, value in vars(args).items()
              if name not in ("members", "worker", "out", "cpu_devices", "collect_only", "set")]
  settings += [f"--set={pair}" for pair in args.set]
  settings += ["--collect-only"] if args.collect_only else []
  for members in [int(m) for m in args.members.split(",")]:
    done = subprocess.run([sys.executable, __file__, "--worker", f"--members={members}",
                           *settings], env=env, stdout=subprocess.PIPE, text=True)
    if done.returncode:
      print(f"S = {members}: failed (exit {done.returncode}), stopping here", file=sys.stderr)
      break
    rows.append(json.loads(done.stdout.strip().splitlines()[-1]))
    print(f"  S = {members}: {rows[-1]['env_steps_per_s']:,.0f} env steps/s", file=sys.stderr,
          flush=True)
  base = rows[0]["env_steps_per_s"] if rows and rows[0]["members"] == 1 else None
  lines = ["| members | compile (s) | env steps/s | updates/s | memory (GB) | x sequential |",
           "|---|---|---|---|---|---|"]
  for r in rows:
    ratio = f"{r['env_steps_per_s'] / base:.2f}" if base else "-"
    lines.append(f"| {r['members']} | {r['compile_s']:.1f} | {r['env_steps_per_s']:,.0f} | "
                 f"{r['updates_per_s']:,.0f} | {r['memory_gb']:.2f} | {ratio} |")
  print(f"{platform.node()}, {rows[0]['devices'] if rows else '?'} "
        f"{rows[0]['platform'] if rows else ''} device(s), {args.env} {args.agent} "
        f"({args.preset}{', ' + ', '.join(args.set) if args.set else ''}), {args.num_envs} envs "
        f"and batch {args.batch_size} per member"
        f"{', collect only (learning off)' if args.collect_only else ''}\n"
        + "\n".join(lines))
  os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
  with open(args.out, "w") as f:
    json.dump({"date": time.strftime("%Y-%m-%d"), "machine": platform.node(),
               "settings": {k: v for k, v in vars(args).items() if k != "worker"},
               "rows": rows}, f, indent=1)


if __name__ == "__main__":
  main()
