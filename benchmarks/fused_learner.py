"""The fused learner against XLA's, in one process: D4PG's update as each robot's preset ships
it (its networks, precision and batch), K updates in one compiled `lax.scan` over K random
batches, on the XLA path and on the fused path (agents/fused.py, agents/pallas_mlp.py) with
each --tiles setting.
Reports updates/s, the ratio to XLA's, the launches of one compiled update, the fraction of
the measured matmul peak in the networks' compute dtype from XLA's FLOP count of one update
(learner_throughput.py's count, which includes the matrix products), and how far one fused
update's metrics and new parameters are from XLA's on the same state and batch.

    python benchmarks/fused_learner.py --robots Hopper,Humanoid      # on a GPU
    python benchmarks/fused_learner.py --robots Hopper --batch 256 --updates 2   # CPU smoke
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time

import common
import learner_throughput as lt


def _batches(rng, k, batch, obs, act):
  from mjx_hopper import replay
  import numpy as np
  return replay.Transition(
      obs=rng.normal(size=(k, batch, obs)).astype(np.float32),
      action=rng.uniform(-1, 1, (k, batch, act)).astype(np.float32),
      reward=rng.normal(size=(k, batch)).astype(np.float32),
      discount=np.full((k, batch), 0.99**5, np.float32),
      next_obs=rng.normal(size=(k, batch, obs)).astype(np.float32))


def _agent(case, learner):
  from mjx_hopper import agents
  from mjx_hopper.agents import d4pg
  if case["agent"] != "d4pg":
    raise SystemExit(f"fused_learner times D4PG, got {case['agent']}")
  cfg = agents.config("d4pg", case["preset"], **case["overrides"])
  return d4pg.make(case["obs"], case["act"], cfg, learner=learner)


GEMM_NAMES = ("gemm", "xmma", "nvjet", "cutlass")  # cuBLAS's, CUTLASS's and Triton's products


def _profile(compiled, state, data, updates):
  """Per update: the GPU's kernels, their summed microseconds, those of the matrix products and
  of the Pallas kernels, and the 12 kernels (by name) that took the most, from one traced call."""
  import collections
  import gzip
  import pathlib
  import tempfile
  import jax
  folder = tempfile.mkdtemp()
  with jax.profiler.trace(folder, create_perfetto_trace=True):
    jax.block_until_ready(compiled(state, *data))
  path = next(pathlib.Path(folder).glob("**/*.trace.json.gz"))
  with gzip.open(path) as f:
    events = json.load(f)["traceEvents"]
  gpu = {e["pid"] for e in events if e.get("ph") == "M" and e.get("name") == "process_name"
         and "GPU" in e["args"]["name"]}
  streams = {(e["pid"], e["tid"]) for e in events if e.get("ph") == "M"
             and e.get("name") == "thread_name" and e["args"]["name"].startswith("Stream")}
  kernels = [e for e in events if e.get("ph") == "X" and e["pid"] in gpu
             and (e["pid"], e.get("tid")) in streams]
  by_name, count = collections.Counter(), collections.Counter()
  for e in kernels:
    by_name[e["name"][:60]] += e["dur"] / updates
    count[e["name"][:60]] += 1 / updates
  total = sum(by_name.values())
  return {"kernels": len(kernels) / updates, "kernel_us": total,
          "gemm_us": sum(t for n, t in by_name.items() if any(g in n for g in GEMM_NAMES)),
          "pallas_us": sum(t for n, t in by_name.items() if "_kernel" in n),
          "top": [[n, round(t, 1), round(count[n], 1)] for n, t in by_name.most_common(12)]}


def _timed(case, learner, updates, data, calls, profile=False):
  """updates/s of `updates` updates per compiled call (median of `calls`), compile seconds,
  and the launches of one compiled update."""
  import jax
  agent = _agent(case, learner)
  state = agent.init(jax.random.PRNGKey(0))

  def run(state, data, key):
    def step(state, inputs):
      b, k = inputs
      return agent.update(state, b, k)
    state, metrics = jax.lax.scan(step, state, (data, jax.random.split(key, updates)))
    return state, jax.tree.map(lambda m: m[-1], metrics)
  timed = common.Timed(jax.jit(run), state, data, jax.random.PRNGKey(1))
  rate = updates / statistics.median(timed() for _ in range(calls))
  one = jax.tree.map(lambda x: x[0], data)
  kernels = lt.count_kernels(jax.jit(agent.update).lower(
      state, one, jax.random.PRNGKey(0)).compile().as_text())
  traced = _profile(timed.compiled, timed.state, timed.args, updates) if profile else None
  return rate, timed.trace_s + timed.compile_s, kernels, traced


def _agreement(case, data):
  """Largest relative difference, fused against XLA, over one update's metrics, and the
  largest difference of its new parameters over the largest XLA parameter (one scale for all:
  Adam's first step moves each parameter by about the learning rate, whatever its gradient)."""
  import jax
  import numpy as np
  one = jax.tree.map(lambda x: x[0], data)
  results = {}
  for learner in ("xla", "fused"):
    agent = _agent(case, learner)
    state = agent.init(jax.random.PRNGKey(0))
    results[learner] = jax.jit(agent.update)(state, one, jax.random.PRNGKey(0))

  def rel(a, b):
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-12))
  (xs, xm), (fs, fm) = results["xla"], results["fused"]
  diff = max(jax.tree.leaves(jax.tree.map(lambda a, b: float(np.abs(a - b).max()),
                                            (fs.policy, fs.critic), (xs.policy, xs.critic))))
  scale = max(float(np.abs(b).max()) for b in jax.tree.leaves((xs.policy, xs.critic)))
  return {"metrics": {k: rel(fm[k], xm[k]) for k in xm}, "params_max": diff / scale,
          "params_max_abs": diff}


def _critic_parts(case, tiles, calls=5, repeats=20):
  """Seconds of the critic's forward pass, and of its forward and backward passes (gradients of
  the parameters and the action), XLA's and fused, at the preset's batch."""
  import jax
  import jax.numpy as jnp
  from mjx_hopper.agents import fused, networks, pallas_mlp
  from mjx_hopper.agents.base import COMPUTE_DTYPES
  from mjx_hopper import agents
  cfg = agents.config("d4pg", case["preset"], **case["overrides"])
  net = networks.Critic(cfg.critic_layers, cfg.num_atoms, COMPUTE_DTYPES[cfg.compute_dtype])
  k = jax.random.split(jax.random.PRNGKey(0), 3)
  obs = jax.random.normal(k[0], (case["batch"], case["obs"]))
  act = jax.random.uniform(k[1], (case["batch"], case["act"]), minval=-1, maxval=1)
  params = net.init(k[2], obs, act)
  out = {}
  for name, apply in (("xla", net.apply),
                      ("fused", fused.critic(net, pallas_mlp.Tiles(*map(int, tiles.split(",")))))):
    def fwd(p, o, a):
      return jnp.sum(apply(p, o, a) ** 2)
    for part, fn in (("forward", fwd), ("forward_backward", jax.grad(fwd, argnums=(0, 2)))):
      def loop(p, o, a, fn=fn):  # `repeats` calls in one program, each on a shifted input
        def body(i, acc):
          r = fn(p, o + i * 1e-3, a)
          return acc + sum(jnp.sum(x) for x in jax.tree.leaves(r))
        return jax.lax.fori_loop(0, repeats, body, 0.0)
      f = jax.jit(loop)
      f(params, obs, act).block_until_ready()
      times = []
      for _ in range(calls):
        t0 = time.perf_counter()
        f(params, obs, act).block_until_ready()
        times.append((time.perf_counter() - t0) / repeats)
      out[f"{name}_{part}_us"] = 1e6 * statistics.median(times)
  print(f"  {case['label']} critic alone: {out}", file=sys.stderr, flush=True)
  return out


def rows_for(case, args):
  import jax
  import numpy as np
  rng = np.random.default_rng(0)
  data = _batches(rng, args.updates, case["batch"], case["obs"], case["act"])
  data = jax.device_put(data)
  # XLA's FLOP count of one update, compiled for the host's CPU (its products stay XLA dots).
  agent = _agent(case, "xla")
  cpu = jax.devices("cpu")[0]
  one = jax.tree.map(lambda x: x[0], data)
  cost = jax.jit(agent.update).lower(*jax.device_put(
      (agent.init(jax.random.PRNGKey(0)), one, jax.random.PRNGKey(0)), cpu)).compile()
  cost = cost.cost_analysis()
  flops = float((cost[0] if isinstance(cost, (list, tuple)) else cost)["flops"])
  out = []
  variants = [("xla", None)] + [("fused", t) for t in args.tiles.split(";")]
  for learner, tiles in variants:
    if tiles:
      os.environ["MJX_HOPPER_TILES"] = tiles
    try:
      rate, compile_s, kernels, traced = _timed(case, learner, args.updates, data, args.calls,
                                                args.profile)
    except Exception as e:  # a tile setting the GPU cannot compile: say so, time the others
      print(f"  {case['label']} {learner} {tiles}: failed: {type(e).__name__}: "
            f"{str(e)[:400]}", file=sys.stderr, flush=True)
      out.append({"learner": learner, "tiles": tiles, "error": f"{type(e).__name__}: "
                  f"{str(e)[:400]}"})
      continue
    finally:
      os.environ.pop("MJX_HOPPER_TILES", None)
    print(f"  {case['label']} {learner} {tiles or ''}: {rate:,.0f} updates/s, {kernels} "
          f"launches, compile {compile_s:.1f} s", file=sys.stderr, flush=True)
    out.append({"learner": learner, "tiles": tiles, "updates_per_s": rate,
                "compile_s": compile_s, "kernels": kernels,
                "tflops": rate * flops / 1e12, "profile": traced})
    if traced:
      print(f"    profile: {json.dumps(traced)}", file=sys.stderr, flush=True)
  timed = [r for r in out if "updates_per_s" in r and r["learner"] == "fused"]
  best = max(timed, key=lambda r: r["updates_per_s"])["tiles"] if timed else None
  return {"case": case, "gflop_per_update": flops / 1e9, "rows": out,
          "agreement": _agreement(case, data),
          "critic_alone": _critic_parts(case, best) if best and args.parts else None}


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--robots", default="Hopper,Humanoid")
  parser.add_argument("--batch", type=int, help="default: each preset's")
  parser.add_argument("--updates", type=int, default=20, help="updates per timed call")
  parser.add_argument("--calls", type=int, default=5, help="timed calls (the median counts)")
  parser.add_argument("--tiles", default="32,128,4,3;32,128,8,2",
                      help="fused tile settings, rows,block,num_warps,num_stages; ';' between")
  parser.add_argument("--parts", action="store_true",
                      help="also time the critic alone, XLA's and fused (best tiles)")
  parser.add_argument("--profile", action="store_true",
                      help="also trace one call of each and sum its kernels' times")
  parser.add_argument("--name", default="fused_learner", help="the results file's name")
  args = parser.parse_args()
  import jax
  cases = lt.cases("d4pg", "gpu", args.robots, args.batch, {})
  for c in cases:
    c["label"] = c["robot"]
  peaks = {"float32": lt.matmul_peak("float32") / 1e12,
           "bfloat16": lt.matmul_peak("bfloat16") / 1e12}
  results = []
  for case in cases:
    r = rows_for(case, args)
    peak = peaks[case["overrides"].get("compute_dtype", "float32")]
    xla = r["rows"][0].get("updates_per_s")
    for row in r["rows"]:
      if "updates_per_s" in row:
        row["fraction_of_peak"] = row["tflops"] / peak
        row["x_xla"] = row["updates_per_s"] / xla if xla else None
    results.append(r)
  device = jax.devices()[0]
  commit = os.environ.get("MJX_HOPPER_COMMIT") or subprocess.run(
      ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
      cwd=os.path.dirname(os.path.abspath(__file__))).stdout
  print(f"# fused learner, {time.strftime('%Y-%m-%d')}, {device.device_kind}, jax "
        f"{jax.__version__}\n")
  print(common.table(
      ["robot", "dtype", "batch", "learner", "tiles", "updates/s", "x XLA", "launches",
       "TFLOP/s", "% of peak", "compile (s)"],
      [[r["case"]["robot"], r["case"]["overrides"].get("compute_dtype", "float32"),
        r["case"]["batch"], row["learner"], row.get("tiles") or "",
        f"{row['updates_per_s']:,.0f}", f"{row['x_xla']:.2f}", row["kernels"],
        f"{row['tflops']:.1f}", f"{100 * row['fraction_of_peak']:.1f}%",
        f"{row['compile_s']:.1f}"] for r in results for row in r["rows"]
       if "updates_per_s" in row]))
  for r in results:
    print(f"{r['case']['robot']}: fused vs XLA, largest relative difference: metrics "
          f"{max(r['agreement']['metrics'].values()):.2e}, new params "
          f"{r['agreement']['params_max']:.2e}")
  common.write_results(args.name, {
      "date": time.strftime("%Y-%m-%d"), "machine": platform.node(),
      "device": device.device_kind, "jax": jax.__version__, "commit": commit.strip(),
      "peaks_tflops": peaks, "results": results})


if __name__ == "__main__":
  main()
