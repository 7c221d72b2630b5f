"""Learner throughput: updates/s at a given batch size for each agent preset, with compile time
and the achieved FLOP/s against this machine's measured fp32 matmul peak, in one run: K updates
in one compiled `lax.scan` over K random Hopper-sized batches, split over the devices as the
trainer does (BENCHMARKS.md, "Learner throughput"); FLOPs are XLA's count for one update.

    python benchmarks/learner_throughput.py                     # CPU: 1 and 2 XLA devices
    python benchmarks/learner_throughput.py --devices 1         # on a GPU
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time

import common

OBS, ACT = 15, 3  # Hopper


def matmul_peak(n: int = 2048, repeats: int = 10) -> float:
  """Best fp32 FLOP/s of n x n matmuls, one per device, all devices at once."""
  import jax
  import jax.numpy as jnp
  from jax.sharding import Mesh, NamedSharding, PartitionSpec as P

  devices = jax.local_devices()
  sharding = NamedSharding(Mesh(devices, ("d",)), P("d"))
  a = jax.device_put(jax.random.normal(jax.random.PRNGKey(0), (len(devices), n, n)), sharding)
  f = jax.jit(lambda x: jnp.einsum("dij,djk->dik", x, x), out_shardings=sharding)
  f(a).block_until_ready()
  best = float("inf")
  for _ in range(repeats):
    t0 = time.perf_counter()
    f(a).block_until_ready()
    best = min(best, time.perf_counter() - t0)
  return 2 * n**3 * len(devices) / best


def learner_rows(agent_name: str, presets: list[str], batch: int, updates: int) -> list[dict]:
  import jax
  import numpy as np
  from jax.sharding import Mesh, NamedSharding, PartitionSpec as P

  from mjx_hopper import agents, replay

  devices = jax.local_devices()
  mesh = Mesh(devices, ("devices",))
  rng = np.random.default_rng(0)

  def batches(k):
    return replay.Transition(
        obs=rng.normal(size=(k, batch, OBS)).astype(np.float32),
        action=rng.uniform(-1, 1, (k, batch, ACT)).astype(np.float32),
        reward=rng.normal(size=(k, batch)).astype(np.float32),
        discount=np.full((k, batch), 0.99**5, np.float32),
        next_obs=rng.normal(size=(k, batch, OBS)).astype(np.float32))

  rows = []
  for preset in presets:
    agent = agents.make(agent_name, OBS, ACT, agents.config(agent_name, preset))
    state = agent.init(jax.random.PRNGKey(0))
    one = jax.tree.map(lambda x: x[0], batches(1))
    cost = jax.jit(lambda s, b, k: agent.update(s, b, k)).lower(
        state, one, jax.random.PRNGKey(0)).compile().cost_analysis()
    flops = float((cost[0] if isinstance(cost, (list, tuple)) else cost).get("flops", np.nan))

    def run(state, data, key):
      def step(state, inputs):
        b, k = inputs
        return agent.update(state, b, k, axis_name="devices")
      keys = jax.random.split(key, updates)
      state, metrics = jax.lax.scan(step, state, (data, keys))
      return state, jax.tree.map(lambda m: m[-1], metrics)

    data_spec = replay.Transition(*[P(None, "devices")] * 5)
    run = jax.jit(jax.shard_map(run, mesh=mesh, in_specs=(P(), data_spec, P()),
                                out_specs=(P(), P()), check_vma=False))
    data = jax.device_put(batches(updates), jax.tree.map(
        lambda s: NamedSharding(mesh, s), data_spec, is_leaf=lambda x: isinstance(x, P)))
    state = jax.device_put(state, NamedSharding(mesh, P()))
    timed = common.Timed(run, state, data, jax.random.PRNGKey(1))
    compile_s = timed.trace_s + timed.compile_s
    rate = updates / statistics.median(timed() for _ in range(3))
    losses = {k: float(v) for k, v in timed.out.items()}
    if not all(np.isfinite(v) for v in losses.values()):
      raise SystemExit(f"{agent_name}/{preset}: non-finite metrics {losses}")
    rows.append({"agent": agent_name, "preset": preset, "platform": devices[0].platform,
                 "devices": len(devices), "batch": batch, "compile_s": compile_s,
                 "updates_per_s": rate, "gflop_per_update": flops / 1e9,
                 "gflops": rate * flops / 1e9})
    print(f"  {agent_name}/{preset} x{len(devices)}: {rate:,.0f} updates/s, "
          f"{rate * flops / 1e9:.1f} GFLOP/s, compile {compile_s:.1f} s", file=sys.stderr,
          flush=True)
  return rows


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--agents", default="d4pg", help="comma-separated agent names")
  parser.add_argument("--presets", default="seed,gpu,cpu")
  parser.add_argument("--batch", type=int, default=256)
  parser.add_argument("--updates", type=int, default=100, help="updates per timed call")
  parser.add_argument("--devices", default="1,2",
                      help="XLA CPU device counts (on a GPU: GPUs used)")
  parser.add_argument("--json", help="also write the rows to this file")
  parser.add_argument("--worker", help=argparse.SUPPRESS)  # the arguments, as JSON
  args = parser.parse_args()
  if args.worker:  # one device count per process: XLA reads the flag at start-up
    args = argparse.Namespace(**json.loads(args.worker))
    rows = [r for a in args.agents.split(",")
            for r in learner_rows(a, args.presets.split(","), args.batch, args.updates)]
    print(json.dumps({"peak": matmul_peak(), "rows": rows}))
    return

  rows, peaks = [], {}
  for d in [int(x) for x in args.devices.split(",")]:
    if args.batch % d:
      raise SystemExit(f"--batch {args.batch} must divide over {d} devices")
    result = common.worker(__file__, vars(args), d)
    if result is None:
      raise SystemExit(1)
    peaks[d] = result["peak"] / 1e9
    rows += result["rows"]
  print(f"# learner throughput, {time.strftime('%Y-%m-%d')}, {platform.node()}, "
        f"{os.cpu_count()} CPUs\n")
  print(common.table(
      ["agent", "preset", "platform", "devices", "batch", "compile (s)", "updates/s",
       "GFLOP/update", "GFLOP/s", "% of matmul peak"],
      [[r["agent"], r["preset"], r["platform"], r["devices"], r["batch"], f"{r['compile_s']:.1f}",
        f"{r['updates_per_s']:,.0f}", f"{r['gflop_per_update']:.3f}", f"{r['gflops']:.1f}",
        f"{100 * r['gflops'] / peaks[r['devices']]:.0f}%"] for r in rows]))
  print("\nmeasured fp32 matmul peak (GFLOP/s): "
        + ", ".join(f"{d} device(s): {p:,.1f}" for d, p in peaks.items()))
  if args.json:
    with open(args.json, "w") as f:
      json.dump({"peaks_gflops": peaks, "rows": rows}, f, indent=1)


if __name__ == "__main__":
  main()
