"""Where a sweep's training iteration spends the GPU's time, kernel by kernel.

    python benchmarks/research/sweep_profile.py --members 1,16 --out /tmp/sweep_profile   # GPU

For each S (a fresh process each), it builds sweep_throughput.py's sweep of S members (D4PG on
Hopper, learning from the first iteration), compiles and warms its chunk, times `--chunks`
chunks, then runs one more chunk under `jax.profiler.trace` and reads the trace's device
events: the kernels on the GPU's streams. It prints, per iteration of the chunk:
  wall      the chunk's wall time over its iterations (untraced, as sweep_throughput times it);
  busy      the time at least one kernel ran (the union of the kernels' intervals);
  kernels   how many kernels ran, their summed time, and the matrix products' share of it;
and the compiled program's ops that took the most time, with their kernels. XLA runs stretches
of the program as command buffers (CUDA graphs), so an op can be a whole loop body: the op with
8 x ~170 kernels is the iteration's 8 updates, every member's at once. busy near wall means the
GPU never waits for the host. The device events of the traced chunk are written to
OUT_S{S}.json.gz for a closer look.
"""

from __future__ import annotations

import argparse
import collections
import gzip
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time

# The matrix-product kernels (cuBLAS's, CUTLASS's, Triton's GEMM fusions), by name.
GEMM_NAMES = ("gemm", "xmma", "nvjet", "cutlass")


def device_events(trace_dir: str) -> list[dict]:
  """The events of the GPU's lines in the trace written under trace_dir, each with its line's
  name as "thread": the streams' kernels ("Stream #..."), and lines derived from them."""
  path, = pathlib.Path(trace_dir).glob("plugins/profile/*/*.trace.json.gz")
  with gzip.open(path) as f:
    events = json.load(f)["traceEvents"]
  process = {e["pid"]: e["args"]["name"] for e in events
             if e.get("ph") == "M" and e.get("name") == "process_name"}
  thread = {(e["pid"], e["tid"]): e["args"]["name"] for e in events
            if e.get("ph") == "M" and e.get("name") == "thread_name"}
  return [dict(e, thread=thread.get((e["pid"], e.get("tid")), "")) for e in events
          if e.get("ph") == "X" and "GPU" in process.get(e["pid"], "")]


def summarise(kernels: list[dict], iterations: int) -> dict:
  """Per iteration: the GPU's busy time, its kernels and their time, the matrix products' share,
  and the compiled program's ops that took the most time. XLA runs stretches of the program as
  command buffers (CUDA graphs), so an op can be a whole loop body, such as the updates'."""
  intervals = sorted((e["ts"], e["ts"] + e["dur"]) for e in kernels)
  busy, end = 0.0, float("-inf")
  for start, stop in intervals:
    if stop > end:
      busy += stop - max(start, end)
      end = stop
  by_op, count = collections.Counter(), collections.Counter()
  gemm = collections.Counter()
  for e in kernels:
    op = e.get("args", {}).get("hlo_op", "?")
    by_op[op] += e["dur"]
    count[op] += 1
    if any(word in e["name"] for word in GEMM_NAMES):
      gemm[op] += e["dur"]
  ms = lambda us: us / 1000 / iterations  # noqa: E731 (per iteration, in ms)
  return {"busy_ms": ms(busy), "kernels": len(kernels) / iterations,
          "kernel_ms": ms(sum(e["dur"] for e in kernels)), "gemm_ms": ms(sum(gemm.values())),
          "ops": [{"op": op, "ms": ms(t), "kernels": count[op] / iterations,
                   "gemm_ms": ms(gemm[op])} for op, t in by_op.most_common(8)]}


def measure(args) -> dict:
  import jax

  # sweep_throughput.py is in benchmarks/, this script's parent folder.
  sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
  from sweep_throughput import run_sweep
  cfg, compiled, state, _, seconds = run_sweep(argparse.Namespace(
      **vars(args), env="Hopper", agent="d4pg", preset="gpu", collect_only=False))
  wall_ms = seconds * 1000 / (args.chunks * args.chunk)
  trace_dir = tempfile.mkdtemp()
  with jax.profiler.trace(trace_dir):
    jax.block_until_ready(compiled(state))
  events = device_events(trace_dir)
  with gzip.open(f"{args.out}_S{args.members}.json.gz", "wt") as f:
    json.dump([{k: e[k] for k in ("name", "ts", "dur", "thread", "args") if k in e}
               for e in events], f)
  kernels = [e for e in events if e["thread"].startswith("Stream")]
  return {"members": args.members, "wall_ms": wall_ms,
          "env_steps_per_s": args.members * cfg.train.steps_per_iteration / wall_ms * 1000,
          **summarise(kernels, args.chunk)}


def main() -> None:
  p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  p.add_argument("--members", default="1,16", help="comma-separated sweep sizes")
  p.add_argument("--num-envs", type=int, default=512, help="envs per member")
  p.add_argument("--unroll-length", type=int, default=4)
  p.add_argument("--batch-size", type=int, default=1024, help="per member")
  p.add_argument("--replay-ratio", type=float, default=4.0)
  p.add_argument("--replay-size", type=int, default=1_000_000, help="transitions per member")
  p.add_argument("--chunk", type=int, default=10, help="iterations per chunk")
  p.add_argument("--chunks", type=int, default=3, help="timed chunks")
  p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                 help="a D4PG setting, such as compute_dtype=bfloat16 (repeatable)")
  p.add_argument("--out", default="runs/sweep_profile", help="prefix of the written files")
  p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
  args = p.parse_args()
  if args.worker:
    args.members = int(args.members)
    print(json.dumps(measure(args)))
    return
  os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
  rows = []
  for members in args.members.split(","):
    argv = [f"--{k.replace('_', '-')}={v}" for k, v in vars(args).items()
            if k not in ("members", "worker", "set")] + [f"--set={pair}" for pair in args.set]
    done = subprocess.run([sys.executable, __file__, "--worker", f"--members={members}", *argv],
                          stdout=subprocess.PIPE, text=True)
    if done.returncode:
      print(f"S = {members}: failed (exit {done.returncode})", file=sys.stderr)
      continue
    rows.append(json.loads(done.stdout.strip().splitlines()[-1]))
  with open(f"{args.out}.json", "w") as f:
    json.dump({"date": time.strftime("%Y-%m-%d"), "settings": vars(args), "rows": rows}, f,
              indent=1)
  print("| members | wall ms/iteration | GPU busy ms | kernels | kernel ms | of which products "
        "| env steps/s |")
  print("|---|---|---|---|---|---|---|")
  for r in rows:
    print(f"| {r['members']} | {r['wall_ms']:.2f} | {r['busy_ms']:.2f} | {r['kernels']:.0f} | "
          f"{r['kernel_ms']:.2f} | {r['gemm_ms']:.2f} | {r['env_steps_per_s']:,.0f} |")
  for r in rows:
    print(f"\nS = {r['members']}, the ops that took the most time (ms per iteration):")
    for op in r["ops"]:
      print(f"  {op['ms']:7.3f} ms  {op['kernels']:6.0f} kernels  products {op['gemm_ms']:.3f} ms"
            f"  {op['op']}")


if __name__ == "__main__":
  main()
