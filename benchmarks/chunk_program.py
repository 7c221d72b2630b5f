"""The training chunk as a program: its size, its compile time and its steady env steps/s, for a
robot's preset, here and (with --checkout DIR) in another checkout, in turns, each in a fresh
process with an empty compile cache. The episode starts' refill, where the code has one, is
compiled and timed with it. With --split, it also times compiling the chunk as two programs in
two threads, its collection (acting, env steps, replay insert) and its learning (replay samples,
updates), against the one program: what splitting the chunk would bring to a run's start.

    python benchmarks/chunk_program.py --checkout /tmp/before --checkout-name d8161c9
    bash benchmarks/gpu.sh "python benchmarks/chunk_program.py --kind gpu --label h100 ..."
"""

from __future__ import annotations

import functools
import json
import os
import statistics
import subprocess
import sys
import tempfile

import common


def measure(args) -> dict:
  """The chunk's size and compile time, and env steps/s over args.chunks chunks."""
  import mjx_hopper
  with tempfile.TemporaryDirectory() as cache:
    if hasattr(mjx_hopper, "setup"):  # empty: every program compiles
      mjx_hopper.setup(compile_cache=cache)
    else:  # code from before mjx_hopper.setup
      mjx_hopper.use_compile_cache(cache)
    import jax
    import numpy as np

    try:
      trainers = common.project_module("run.trainers")
    except ModuleNotFoundError:  # its name before the checkpoint readers had their own module
      trainers = common.project_module("run.runs")
    presets = common.project_module("settings.presets")
    cfg = presets.run_config(args.env, args.kind)
    members = getattr(cfg, "member_settings", None) or cfg.members  # its name before c1d0d21
    plan = common.resolved(cfg)
    trainer = trainers.build(plan)
    state = trainers.init(plan, trainer, members())
    chunk = getattr(trainer, "chunk", None) or trainer.train_chunk  # before EpisodeStarts
    refill = getattr(trainer, "refill", None)
    figures = {"lowered_chars": len(chunk.lower(state).as_text())}
    timed = common.Timed(chunk, state, trainer=trainer if refill else None)
    figures["compiled_instructions"] = sum(
        " = " in line for line in timed.compiled.as_text().splitlines())
    figures.update(trace_s=timed.trace_s, compile_s=timed.compile_s)
    if refill is not None:
      try:
        lowered = refill.lower(timed.state.env, np.False_)
      except (TypeError, ValueError):  # code from before the refill began init's envs
        lowered = refill.lower(timed.state.env)
      figures["refill_instructions"] = sum(
          " = " in line for line in lowered.compile().as_text().splitlines())
    timed(2)  # past the first chunks' replay warm-up
    seconds = timed(args.chunks)
    steps = cfg.train.steps_per_iteration * cfg.train.iterations_per_chunk * args.chunks
    figures["env_steps_per_s"] = steps / seconds
    figures["platform"] = jax.devices()[0].platform
    if args.split:
      figures.update(split_compile(trainer, timed.state))
  return figures


def split_compile(trainer, state) -> dict:
  """Seconds to compile the chunk's collection and learning as two programs at once, in two
  threads (XLA's compile releases Python's lock): each, and both."""
  import concurrent.futures
  import time

  import jax

  from mjx_hopper.core import replay, train
  from mjx_hopper.envs import EpisodeStarts

  cfg, agent = trainer.config, trainer.agent
  where = train.layout(trainer.num_members, jax.devices())
  train_env = EpisodeStarts.for_steps(trainer.env, cfg.unroll_length * cfg.iterations_per_chunk)
  each_member = where.each_member

  def collection(state):
    def iteration(state, _):
      key, act_key = each_member(lambda k: tuple(jax.random.split(k)))(state.key)
      env, ret, steps, _ = each_member(functools.partial(
          train.collect, agent, train_env, cfg.unroll_length))(
              state.agent, state.env, state.episode_return, act_key)
      return state._replace(env=env, episode_return=ret, key=key,
                            replay=each_member(replay.insert)(state.replay, steps)), None
    return jax.lax.scan(iteration, state, None, length=cfg.iterations_per_chunk)[0]

  def learning(state):
    learn = functools.partial(train.learn, agent, cfg, where, False)

    def iteration(state, _):
      key, learn_key = each_member(lambda k: tuple(jax.random.split(k)))(state.key)
      agent_state, metrics = each_member(
          lambda a, b, k: learn(a, b, k, cfg.updates_per_iteration))(
              state.agent, state.replay, learn_key)
      return state._replace(agent=agent_state, key=key), metrics
    state, metrics = jax.lax.scan(iteration, state, None, length=cfg.iterations_per_chunk)
    return state, jax.tree.map(lambda m: m.mean(0), metrics)

  member_metrics = jax.sharding.PartitionSpec(train.MEMBERS)
  programs = {
      "collection": jax.shard_map(collection, mesh=where.mesh, in_specs=(where.specs,),
                                  out_specs=where.specs, check_vma=False),
      "learning": jax.shard_map(learning, mesh=where.mesh, in_specs=(where.specs,),
                                out_specs=(where.specs, member_metrics), check_vma=False)}
  shapes = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=x.sharding),
                        state)
  lowered = {name: jax.jit(fn, donate_argnums=0).lower(shapes) for name, fn in programs.items()}

  def compile_s(low):
    start = time.perf_counter()
    low.compile()
    return time.perf_counter() - start
  # Both at once, each timed in its thread (a second compile would come from the cache).
  start = time.perf_counter()
  with concurrent.futures.ThreadPoolExecutor(2) as pool:
    seconds = dict(zip(lowered, pool.map(compile_s, lowered.values())))
  figures = {f"{name}_compile_s": s for name, s in seconds.items()}
  figures["split_compile_s"] = time.perf_counter() - start
  return figures


def run_in(code: str | None, work: dict) -> dict:
  """`measure(work)` in a fresh process, on the code laid out as installed in `code`."""
  env = dict(os.environ)
  if code:
    env["PYTHONPATH"] = os.pathsep.join([code, env.get("PYTHONPATH", "")])
  done = subprocess.run([sys.executable, __file__, "--worker", json.dumps(work)],
                        env=env, stdout=subprocess.PIPE, text=True, check=True)
  return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
  p = common.parser(__doc__)
  p.add_argument("--env", default="Hopper")
  p.add_argument("--kind", default="cpu", help="the robot preset: cpu or gpu")
  p.add_argument("--chunks", type=int, default=10, help="chunks timed")
  p.add_argument("--rounds", type=int, default=2)
  p.add_argument("--checkout", default=None, help="another checkout's folder to time beside")
  p.add_argument("--checkout-name", default=None, help="its name in the results")
  p.add_argument("--label", default="cpu")
  p.add_argument("--split", action="store_true",
                 help="also compile the chunk as two programs (this checkout only)")
  args = common.parse(p, measure)
  work = {"env": args.env, "kind": args.kind, "chunks": args.chunks, "split": args.split}
  codes = {"this checkout": None}
  with tempfile.TemporaryDirectory(prefix="chunk_program_") as installed:
    if args.checkout:
      codes[args.checkout_name or args.checkout] = common.installed_layout(args.checkout,
                                                                           installed)
    runs: dict[str, list[dict]] = {name: [] for name in codes}
    for i in range(args.rounds):
      for name, code in (codes.items() if i % 2 == 0 else reversed(codes.items())):
        runs[name].append(run_in(code, work))
        print(name, json.dumps(runs[name][-1]), flush=True)
  medians = {name: {k: statistics.median(r[k] for r in rs) for k in rs[0]
                    if isinstance(rs[0][k], (int, float))} for name, rs in runs.items()}
  for name, figures in medians.items():
    print(name, {k: round(v, 2) for k, v in figures.items()})
  common.write_results(f"chunk_program_{args.label}", {
      "preset": f"{args.env} {args.kind}", "medians": medians, "runs": runs})


if __name__ == "__main__":
  main()
