"""XLA:CPU's compile options for the test suite, weighed on the suite's two kinds of program:
the Hopper's random-action episodes (128 episodes of 1,000 steps, as tests/conftest.py's
mjx_episodes runs them) and the notebook's tiny D4PG trainer (its chunk and evaluation). Each
option set compiles both in a fresh process of two CPU devices with no compile cache, in turns
over `--rounds`; the figures are each set's compile and run seconds.

    python benchmarks/compile_flags.py --rounds 2

Writes benchmarks/results/compile_flags_cpu.json. Run it on an otherwise idle machine.
"""

from __future__ import annotations

import os
import statistics
import time

import common

# The suite's flags before this measurement (tests/conftest.py), and each candidate added to
# them. jaxlib 0.12 refuses --xla_cpu_disable_loop_unrolling, --xla_cpu_disable_slp_vectorizer
# and --xla_cpu_optimize_for_size at start-up, though its library names them.
SUITE = "--xla_cpu_multi_thread_eigen=false --xla_backend_optimization_level=1"
CANDIDATES = {
    "level 1": "",
    "level 1, no expensive LLVM passes": "--xla_llvm_disable_expensive_passes=true",
    "level 0": "--xla_backend_optimization_level=0",
    "level 0, no expensive LLVM passes": ("--xla_backend_optimization_level=0 "
                                          "--xla_llvm_disable_expensive_passes=true"),
}


def work(args) -> dict:
  import dataclasses

  import jax

  import mjx_hopper
  mjx_hopper.setup()
  jax.config.update("jax_enable_compilation_cache", False)
  from mjx_hopper import envs
  from mjx_hopper.core import rollout
  from mjx_hopper.faces import notebook
  from mjx_hopper.run import trainers
  from mjx_hopper.settings.config import RunConfig
  from mjx_hopper.settings.plan import resolve

  out = {}
  env = envs.make("Hopper")
  random = rollout.random_policy(env.action_size)
  episodes = jax.jit(lambda key: rollout.episodes(env, random, key, 128))
  key = jax.random.PRNGKey(1)
  t0 = time.perf_counter()
  compiled = episodes.lower(key).compile()
  t1 = time.perf_counter()
  jax.block_until_ready(compiled(key))
  out["episodes_compile_s"], out["episodes_run_s"] = t1 - t0, time.perf_counter() - t1

  cfg = dataclasses.replace(notebook.tiny(RunConfig(env="Hopper", agent="d4pg")), log_every=0.0)
  plan = resolve(cfg)
  trainer = trainers.build(plan)
  state = trainers.init(plan, trainer)
  t0 = time.perf_counter()
  chunk = trainer.chunk.lower(state).compile()
  t1 = time.perf_counter()
  for _ in range(2):
    state, metrics = chunk(state)
  jax.block_until_ready(metrics)
  t2 = time.perf_counter()
  evaluate = trainer.evaluate.lower(state.agent, jax.random.split(key, 1)).compile()
  t3 = time.perf_counter()
  jax.block_until_ready(evaluate(state.agent, jax.random.split(key, 1)))
  out.update(chunk_compile_s=t1 - t0, chunk_run_s=t2 - t1, eval_compile_s=t3 - t2,
             eval_run_s=time.perf_counter() - t3)
  return out


def main() -> None:
  p = common.parser(__doc__)
  p.add_argument("--rounds", type=int, default=2)
  p.add_argument("--only", nargs="*", help="candidate names to weigh (default: all)")
  args = common.parse(p, work)
  names = args.only or list(CANDIDATES)
  runs: dict[str, list[dict]] = {name: [] for name in names}
  flags = os.environ.get("XLA_FLAGS", "")
  for _ in range(args.rounds):
    for name in names:
      os.environ["XLA_FLAGS"] = f"{flags} {SUITE} {CANDIDATES[name]}"
      result = common.worker(__file__, {}, devices=2, gpus=False)
      if result:
        runs[name].append(result)
        print(name, {k: round(v, 1) for k, v in result.items()}, flush=True)
  figures = {name: {"flags": CANDIDATES[name], "runs": len(done),
                    **{k: round(statistics.median(r[k] for r in done), 2) for k in done[0]}}
             for name, done in runs.items() if done}
  common.write_results("compile_flags_cpu", figures)


if __name__ == "__main__":
  main()
