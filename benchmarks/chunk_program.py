"""The training chunk as a program: its size, its compile time and its steady env steps/s, for a
robot's preset, here and (with --checkout DIR) in another checkout, in turns, each in a fresh
process with an empty compile cache. The episode starts' refill, where the code has one, is
compiled and timed with it.

    python benchmarks/chunk_program.py --checkout /tmp/before --checkout-name d8161c9
    bash benchmarks/gpu.sh "python benchmarks/chunk_program.py --kind gpu --label h100 ..."
"""

from __future__ import annotations

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

    from mjx_hopper.run import runs
    from mjx_hopper.settings import presets
    cfg = presets.run_config(args.env, args.kind)
    trainer = runs.build(cfg)
    state = runs.init(cfg, trainer, cfg.members())
    chunk = getattr(trainer, "chunk", None) or trainer.train_chunk  # before EpisodeStarts
    refill = getattr(trainer, "refill", None)
    figures = {"lowered_chars": len(chunk.lower(state).as_text())}
    timed = common.Timed(chunk, state, trainer=trainer if refill else None)
    figures["compiled_instructions"] = sum(
        " = " in line for line in timed.compiled.as_text().splitlines())
    figures.update(trace_s=timed.trace_s, compile_s=timed.compile_s)
    if refill is not None:
      lowered = refill.lower(timed.state.env)
      figures["refill_instructions"] = sum(
          " = " in line for line in lowered.compile().as_text().splitlines())
    timed(2)  # past the first chunks' replay warm-up
    seconds = timed(args.chunks)
    steps = cfg.train.steps_per_iteration * cfg.train.iterations_per_chunk * args.chunks
    figures["env_steps_per_s"] = steps / seconds
    figures["platform"] = jax.devices()[0].platform
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
  args = common.parse(p, measure)
  work = {"env": args.env, "kind": args.kind, "chunks": args.chunks}
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
