"""Where a run's first minute goes: a robot preset's start, part by part, each XLA_FLAGS variant
in a fresh process with no compile cache.

    python benchmarks/research/compile_parts.py --env Hopper --kind gpu
    python benchmarks/research/compile_parts.py --env Hopper --kind gpu --variants \
        ";--xla_gpu_enable_triton_gemm=true"

The parts, one after another (`loop.run` overlaps some of them: the chunk compiles in a thread
while init runs, and the evaluation compiles beside the chunk): the imports; `loop.build` (the
env, the agent, the trainer's functions); the first `init` (its compile and run); tracing the
training chunk (`.lower`, Python) and compiling it (XLA); tracing and compiling the evaluation;
the chunk's first call; and the env steps/s of the next calls, so that a flag that compiles
faster but runs slower shows. Variants are `;`-separated XLA_FLAGS strings added to mjx_hopper's
(which turn XLA's Triton GEMM fusions off on a GPU, unless a variant names that flag); the
first is the reference of the ratio columns, and an empty one adds nothing. A variant whose
process fails (an unknown flag) is reported with its error and left out of the table.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time

PARTS = ("import_s", "build_s", "init_s", "chunk_trace_s", "chunk_compile_s", "eval_trace_s",
         "eval_compile_s", "first_chunk_s")


def worker(env: str, kind: str, chunks: int) -> dict:
  """The parts of one start, in this process."""
  t = time.perf_counter()
  import jax
  import jax.numpy as jnp

  from mjx_hopper import loop, presets
  out = {"import_s": time.perf_counter() - t}

  def timed(name, fn):
    t = time.perf_counter()
    value = jax.block_until_ready(fn())
    out[name] = time.perf_counter() - t
    return value

  cfg = presets.run_config(env, kind, eval_episodes=20)
  trainer = timed("build_s", lambda: loop.build(cfg))
  state = timed("init_s", lambda: loop.init(cfg, trainer, cfg.members()))
  lowered = timed("chunk_trace_s", lambda: trainer.train_chunk.lower(state))
  chunk = timed("chunk_compile_s", lowered.compile)
  keys = jnp.stack([jax.random.PRNGKey(0)])
  lowered = timed("eval_trace_s", lambda: trainer.evaluate.lower(state.agent, keys))
  timed("eval_compile_s", lowered.compile)
  state = timed("first_chunk_s", lambda: chunk(state)[0])
  t = time.perf_counter()
  for _ in range(chunks):
    state = chunk(state)[0]
  jax.block_until_ready(state)
  per_chunk = trainer.config.steps_per_iteration * trainer.config.iterations_per_chunk
  out["env_steps_per_s"] = chunks * per_chunk / (time.perf_counter() - t)
  out["device"] = f"{jax.devices()[0].platform} {jax.devices()[0].device_kind}"
  return out


def main() -> None:
  p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  p.add_argument("--env", default="Hopper")
  p.add_argument("--kind", default="gpu", help="the robot preset: gpu or cpu")
  p.add_argument("--variants", default="", help="';'-separated XLA_FLAGS strings")
  p.add_argument("--chunks", type=int, default=3, help="timed chunks after the first")
  p.add_argument("--out", default=None, help="a JSON file for the rows")
  p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
  args = p.parse_args()
  if args.worker:
    print(json.dumps(worker(args.env, args.kind, args.chunks)))
    return
  if args.chunks < 1:
    raise SystemExit(f"--chunks must be >= 1, got {args.chunks}")
  rows = []
  for variant in (v.strip() for v in args.variants.split(";")):
    flags = " ".join(f for f in (os.environ.get("XLA_FLAGS", ""), variant) if f)
    done = subprocess.run([sys.executable, __file__, "--worker", "--env", args.env, "--kind",
                           args.kind, "--chunks", str(args.chunks)], text=True,
                          capture_output=True, env=dict(os.environ, XLA_FLAGS=flags))
    if done.returncode:
      print(f"variant {variant!r} failed:\n{done.stderr[-2000:]}", file=sys.stderr, flush=True)
      continue
    rows.append({"xla_flags": variant, **json.loads(done.stdout.strip().splitlines()[-1])})
    print(f"  {variant or '(default)'}: " + ", ".join(
        f"{k} {rows[-1][k]:.1f}" for k in PARTS), file=sys.stderr, flush=True)
  if not rows:
    raise SystemExit("every variant failed")
  head = "| XLA_FLAGS | " + " | ".join(k[:-2].replace("_", " ") + " (s)" for k in PARTS)
  lines = [head + " | sum (s) | sum ÷ first | env steps/s | steps/s ÷ first |",
           "|---" * (len(PARTS) + 5) + "|"]
  for row in rows:
    row["sum_s"] = sum(row[k] for k in PARTS)
    lines.append(f"| `{row['xla_flags'] or '(default)'}` | "
                 + " | ".join(f"{row[k]:.1f}" for k in PARTS)
                 + f" | {row['sum_s']:.1f} | {row['sum_s'] / rows[0]['sum_s']:.2f} | "
                 f"{row['env_steps_per_s']:,.0f} | "
                 f"{row['env_steps_per_s'] / rows[0]['env_steps_per_s']:.2f} |")
  print(f"{args.env}, {args.kind} preset, {rows[0]['device']}, {platform.node()}, "
        f"{os.cpu_count()} CPUs; one fresh process per variant, no compile cache\n"
        + "\n".join(lines))
  if args.out:
    with open(args.out, "w") as f:
      json.dump({"date": time.strftime("%Y-%m-%d"), "env": args.env, "kind": args.kind,
                 "machine": platform.node(), "rows": rows}, f, indent=1)


if __name__ == "__main__":
  main()
