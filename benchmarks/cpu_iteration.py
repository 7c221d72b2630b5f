"""Where the main job's time goes: its wall clock split into the start, the chunks and the pauses
between them (evaluations, logs, saves), and a chunk split into its parts.

The run: `mjx-hopper train --env Hopper --preset cpu` for --minutes from an empty compile cache,
a row per chunk. The start is the first row's time less its chunk; a chunk's time is its env
steps over its row's rate; a pause is the rest of the time between rows.

The parts, each a compiled program timed alone at the preset's shapes over the same devices, one
chunk's worth: the chunk; the chunk before learning starts (collect and insert); the envs
stepped with random actions (physics and the episode starts' refill); the refill alone; the
replay's samples. Their differences give the physics, the acting and insert, and the learner.

    python benchmarks/cpu_iteration.py --minutes 4               # on the 2-core CPU
    XLA_FLAGS=--xla_cpu_experimental_ynn_fusion_type=+dot \
      python benchmarks/cpu_iteration.py --minutes 4 --label cpu_ynn  # YNNPACK's matrix kernels
"""

from __future__ import annotations

import csv
import dataclasses
import os
import statistics
import subprocess
import sys
import tempfile
import time

import common


def run_split(minutes: float, env: str, kind: str) -> dict:
  """The main job's start, chunk and pause seconds, from its log."""
  with tempfile.TemporaryDirectory() as out:
    command = [sys.executable, "-c", "from mjx_hopper.faces import cli; cli.main()", "train",
               "--env", env, "--agent", "d4pg", "--preset", kind, "--max-minutes", str(minutes),
               "--total-env-steps", "1000000000", "--log-every", "0", "--no-progress",
               "--out-dir", out]
    start = time.time()
    cache = os.path.join(out, "cache")
    # Run from the scratch folder: from a checkout's root, `-c` would import its source folder,
    # not the installed package (the GPU machine's).
    subprocess.run(command, check=True, cwd=out, env=dict(os.environ, MJX_HOPPER_JAX_CACHE=cache),
                   stdout=subprocess.DEVNULL)
    wall = time.time() - start
    with open(os.path.join(out, "log.csv")) as f:
      rows = [r for r in csv.DictReader(f) if r["kind"] == "train"]
  steps = [int(r["env_steps"]) for r in rows]
  ends = [float(r["wall_s"]) for r in rows]  # from loop.run's start, after the imports
  chunks = [(b - a) / float(r["steps_per_s"]) for a, b, r in zip([0] + steps, steps, rows)]
  after_first = ends[-1] - ends[0]
  chunk_s = sum(chunks[1:])
  return {"first_row_run_s": ends[0], "first_chunk_s": chunks[0], "process_s": wall,
          "after_first_row_s": after_first, "chunks_s": chunk_s,
          "pauses_s": after_first - chunk_s, "pause_share": 1 - chunk_s / after_first,
          "chunk_env_steps_per_s": (steps[-1] - steps[0]) / chunk_s,
          "wall_env_steps_per_s": (steps[-1] - steps[0]) / after_first, "env_steps": steps[-1]}


def part_split(env_name: str, kind: str, repeats: int) -> dict:
  """Seconds per chunk of the chunk and of its parts (see the module's docstring)."""
  import mjx_hopper
  with tempfile.TemporaryDirectory() as cache:
    # The devices the CLI makes of the CPU: one per core.
    mjx_hopper.setup(compile_cache=cache, cpu_devices=os.cpu_count() or 1)
    import jax
    import jax.numpy as jnp

    from mjx_hopper.core import replay, rollout
    from mjx_hopper.run import trainers
    from mjx_hopper.settings import presets
    from mjx_hopper.settings.plan import resolve
    cfg = presets.run_config(env_name, kind)
    tc = cfg.train
    steps = tc.unroll_length * tc.iterations_per_chunk

    def per_chunk(jitted, state, *args, **kwargs) -> float:
      timed = common.Timed(jitted, state, *args, **kwargs)
      timed(2)
      return statistics.median(timed() for _ in range(repeats))

    plan = resolve(cfg)
    trainer = trainers.build(plan)

    def fresh():  # each part its own state: a chunk's call consumes (donates) the one it gets
      return trainers.init(plan, trainer)
    learning = per_chunk(trainer.chunk, fresh(), trainer=trainer)
    # The same chunk before learning starts: collection and insert alone.
    waiting = resolve(dataclasses.replace(
        cfg, train=dataclasses.replace(tc, min_replay=tc.replay_size)))
    idle = trainers.build(waiting)
    collecting = per_chunk(idle.chunk, trainers.init(waiting, idle),
                           trainer=idle)
    refill = per_chunk(jax.jit(lambda e, _: (trainer.refill(e, False), None),
                               out_shardings=(trainer.shardings.env, None)), fresh().env, None)
    init, run = rollout.make_stepper(trainer.env, tc.num_envs, steps)
    key = jax.random.PRNGKey(0)
    stepping = per_chunk(run, init(key), key)
    buffer = jax.tree.map(lambda x: x[0], fresh().replay)
    updates = tc.updates_per_iteration * tc.iterations_per_chunk
    n_step = trainer.agent.n_step

    def sample(buffer, key):
      keys = jax.random.split(key, updates)
      batches = jax.vmap(lambda k: replay.sample(buffer, k, tc.batch_size, n_step, 0.99,
                                                 window=n_step))(keys)
      return buffer, jax.tree.map(jnp.sum, batches)
    sampling = per_chunk(jax.jit(sample), buffer, key)
    devices = len(jax.local_devices())
  return {"chunk_s": learning, "learner_s": learning - collecting,
          "replay_sample_s": sampling, "acting_and_insert_s": collecting - stepping,
          "physics_s": stepping - refill, "refill_s": refill, "devices": devices,
          "env_steps_per_chunk": tc.num_envs * steps, "updates_per_chunk": updates}


def main() -> None:
  p = common.parser(__doc__)
  p.add_argument("--env", default="Hopper")
  p.add_argument("--kind", default="cpu", help="the robot preset")
  p.add_argument("--minutes", type=float, default=4.0, help="the main job's length")
  p.add_argument("--repeats", type=int, default=5, help="timed calls of each part")
  p.add_argument("--label", default="cpu")
  args = p.parse_args()
  flags = os.environ.get("XLA_FLAGS")  # as given: mjx_hopper.setup adds its own
  parts = part_split(args.env, args.kind, args.repeats)
  print("parts:", {k: round(v, 3) for k, v in parts.items()}, flush=True)
  split = run_split(args.minutes, args.env, args.kind)
  print("run:", {k: round(v, 3) for k, v in split.items()}, flush=True)
  common.write_results(f"cpu_iteration_{args.label}", {
      "preset": f"{args.env} {args.kind}", "xla_flags": flags, "run": split, "parts": parts})


if __name__ == "__main__":
  main()
