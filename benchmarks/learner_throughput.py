"""Learner throughput: updates/s of each robot's preset (its agent, networks, batch and sizes), K
updates in one compiled scan over random batches split over the devices as the trainer does,
with compile time and FLOP/s (XLA's count, from the program compiled for the CPU,
whose products stay XLA's) against the measured matmul peak in the compute dtype.

    python benchmarks/learner_throughput.py                     # CPU: 1 and 2 XLA devices
    python benchmarks/learner_throughput.py --devices 1 --presets gpu --robots Hopper,Humanoid
"""

from __future__ import annotations

import statistics
import sys
import time

import common


def matmul_peak(dtype: str = "float32", repeats: int = 10) -> float:
  """Best FLOP/s of n x n matmuls in `dtype`, one per device, all devices at once (n = 8,192 on
  a GPU, 2,048 on a CPU)."""
  import jax
  import jax.numpy as jnp
  from jax.sharding import Mesh, NamedSharding, PartitionSpec as P

  devices = jax.local_devices()
  n = 8192 if devices[0].platform == "gpu" else 2048
  sharding = NamedSharding(Mesh(devices, ("d",)), P("d"))
  a = jax.device_put(jax.random.normal(jax.random.PRNGKey(0), (len(devices), n, n), dtype),
                     sharding)
  f = jax.jit(lambda x: jnp.einsum("dij,djk->dik", x, x), out_shardings=sharding)
  f(a).block_until_ready()
  best = float("inf")
  for _ in range(repeats):
    t0 = time.perf_counter()
    f(a).block_until_ready()
    best = min(best, time.perf_counter() - t0)
  return 2 * n**3 * len(devices) / best


def cases(robots: str, kinds: str, overrides: dict, batch_sizes: str | None = None
          ) -> list[dict]:
  """What to time: each robot's preset of each kind (its agent, settings, batch size and
  sizes), `overrides` over its agent's settings, at each of `batch_sizes` (comma-separated;
  None: the preset's)."""
  from mjx_hopper import envs
  from mjx_hopper.settings import presets
  out = []
  for robot in robots.split(","):
    env = envs.make(robot)
    for kind in kinds.split(","):
      preset = presets.get(robot, kind)
      for batch in (map(int, batch_sizes.split(",")) if batch_sizes
                    else [preset.train.batch_size]):
        out.append(dict(robot=robot, agent=preset.agent, preset=kind,
                        overrides={**preset.agent_overrides, **overrides},
                        obs=env.observation_size, act=env.action_size, batch=batch, kind=kind))
  return out


def learner_row(case: dict, updates: int) -> dict:
  """`case` timed: `updates` updates in one compiled scan, the median of 3 calls."""
  import jax
  import numpy as np
  from jax.sharding import NamedSharding, PartitionSpec as P

  from mjx_hopper import agents
  from mjx_hopper.core import replay
  from mjx_hopper.process import parallel
  devices = jax.local_devices()
  mesh = parallel.mesh(devices, ("devices",))
  rng = np.random.default_rng(0)
  agent_name, preset, overrides = case["agent"], case["preset"], case["overrides"]
  obs_size, act_size, batch = case["obs"], case["act"], case["batch"]
  if batch % len(devices):
    raise SystemExit(f"batch {batch} must divide over {len(devices)} devices")

  def batches(k):
    return replay.Transition(
        obs=rng.normal(size=(k, batch, obs_size)).astype(np.float32),
        action=rng.uniform(-1, 1, (k, batch, act_size)).astype(np.float32),
        reward=rng.normal(size=(k, batch)).astype(np.float32),
        discount=np.full((k, batch), 0.99**5, np.float32),
        next_obs=rng.normal(size=(k, batch, obs_size)).astype(np.float32))

  agent = agents.make(agent_name, obs_size, act_size,
                      agents.config(agent_name, preset, **overrides))
  state = agent.init(jax.random.PRNGKey(0))
  one = jax.tree.map(lambda x: x[0], batches(1))
  update = jax.jit(lambda s, b, k: agent.update(s, b, k))
  # Counted on the program compiled for the host's CPU, whose products stay XLA's own dots.
  cost = update.lower(*jax.device_put((state, one, jax.random.PRNGKey(0)),
                                      jax.devices("cpu")[0])).compile().cost_analysis()
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
  label = f"{case['robot']} ({case['kind']})"
  print(f"  {label} {agent_name}/{preset} x{len(devices)}: {rate:,.0f} updates/s, "
        f"{rate * flops / 1e9:.1f} GFLOP/s, compile {compile_s:.1f} s", file=sys.stderr,
        flush=True)
  return {**case, "label": label, "platform": devices[0].platform, "devices": len(devices),
          "compile_s": compile_s, "updates_per_s": rate, "gflop_per_update": flops / 1e9,
          "gflops": rate * flops / 1e9}


def work(args) -> dict:
  """A worker's figures: the matmul peaks and every case's row, on this process's devices."""
  from mjx_hopper.settings import flags
  rows = [learner_row(case, args.updates)
          for case in cases(args.robots, args.presets, flags.overrides(args.set),
                            args.batch_sizes)]
  return {"peak": matmul_peak(), "peak_bf16": matmul_peak("bfloat16"), "rows": rows}


def main() -> None:
  p = common.parser(__doc__)
  p.add_argument("--robots", default="Hopper", help="comma-separated robots")
  p.add_argument("--presets", default="cpu", help="the robots' presets: gpu, cpu or both")
  p.add_argument("--updates", type=int, default=100, help="updates per timed call")
  p.add_argument("--devices", default="1,2", help="XLA CPU device counts (on a GPU: GPUs used)")
  p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                 help="an agent setting for every preset, e.g. compute_dtype=bfloat16")
  p.add_argument("--batch-sizes", default=None,
                 help="comma-separated batch sizes to time (default: each preset's)")
  p.add_argument("--label", default="cpu",
                 help="results: benchmarks/results/learner_throughput_LABEL.json")
  args = common.parse(p, work)  # a worker: one device count, as XLA reads it at start-up
  results = {d: common.worker(__file__, vars(args), d) for d in map(int, args.devices.split(","))}
  if None in results.values():
    raise SystemExit(1)
  peaks = {d: r["peak"] / 1e9 for d, r in results.items()}
  peaks_bf16 = {d: r["peak_bf16"] / 1e9 for d, r in results.items()}
  print("measured matmul peak (GFLOP/s), float32 / bfloat16: " + ", ".join(
      f"{d} device(s): {p:,.1f} / {peaks_bf16[d]:,.1f}" for d, p in peaks.items()))
  common.write_results(f"learner_throughput_{args.label}", {
      "peaks_gflops": peaks, "peaks_bf16_gflops": peaks_bf16,
      "rows": [row for r in results.values() for row in r["rows"]]})


if __name__ == "__main__":
  main()
