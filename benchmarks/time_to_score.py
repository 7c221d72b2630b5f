"""Time to score as users get it: one robot trained with its preset (mjx_hopper.settings.presets)
by `mjx-hopper train`, each seed in a fresh process of its own, timed from process start until an
evaluation reaches the robot's target or the time budget ends; a task of your own (module:Class,
a subclass of a robot) with its robot's preset; --set and --train-set replace one of its agent
settings or of its trainer's layout (`mjx-hopper train`'s flags). Cold (the default): each
process starts on an empty compile cache, checked empty; warm: on a cache that a run of the same
configuration (an earlier seed, not counted) filled. Seeds from 100 up are held out: the presets
were tuned on 0-9. Writes its figures to benchmarks/results/time_to_score_ROBOT_KIND[_LABEL].json,
and to OUT the best seed's final episode (episode.npz, rendered to frame.png and robot.gif where a
renderer works).

    python benchmarks/time_to_score.py Hopper --kind cpu              # on the 2-core CPU
    python benchmarks/time_to_score.py Walker2D --render-only runs/time_to_score/Walker2D_gpu
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

import common

# How the seeds were run, in report.py's words (its METHODS): a file without it is refused there.
METHOD = "fresh, {cache}"


def summarise(rows: list[dict], target: float) -> dict:
  """One seed's figures from its evaluations (`wall_s`: seconds from process start)."""
  hit = next((r for r in rows if r["eval_return"] >= target), None)
  return {"target_wall_s": hit["wall_s"] if hit else None,
          "target_env_steps": hit["env_steps"] if hit else None,
          "best_return": max(r["eval_return"] for r in rows),
          "final_return": rows[-1]["eval_return"], "final_length": rows[-1]["eval_length"],
          "env_steps": rows[-1]["env_steps"], "wall_s": rows[-1]["wall_s"], "curve": rows}


def record_episode(checkpoint_dir: str, member: int, path: str) -> dict:
  """Runs one deterministic episode of `member`'s final policy and saves its qpos."""
  import jax

  from mjx_hopper.core import rollout
  from mjx_hopper.run import checkpoints
  cfg, agent_state, trainer = checkpoints.load_policy(checkpoint_dir, member)
  result = jax.device_get(jax.jit(lambda s, k: rollout.evaluate(
      trainer.env, trainer.agent, s, k, 1, record_qpos=True))(agent_state, jax.random.PRNGKey(7)))
  length = int(result["length"][0])
  np.savez(path, qpos=np.asarray(result["qpos"][:length + 1]), env=cfg.task_id,
           episode_return=float(result["return"][0]))
  return {"episode_return": float(result["return"][0]), "episode_length": length}


def render(out: str) -> list[str]:
  """frame.png (the episode's frame three quarters of the way through) and robot.gif (every
  4th step, at most 250 frames) from OUT/episode.npz."""
  from PIL import Image  # matplotlib's dependency

  from mjx_hopper import envs
  saved = np.load(os.path.join(out, "episode.npz"))
  env = envs.make(str(saved["env"]))
  frames = env.render(saved["qpos"][::4][:250], width=320, height=240)
  paths = [os.path.join(out, "frame.png"), os.path.join(out, "robot.gif")]
  images = [Image.fromarray(frame) for frame in frames]
  images[(3 * len(images)) // 4].save(paths[0])
  images[0].save(paths[1], save_all=True, append_images=images[1:],
                 duration=round(4 * env.dt * 1000), loop=0)
  return paths


# The environment as this script found it, for the runs: not what mjx_hopper.setup sets here.
ENVIRON = dict(os.environ)


def train_in_a_process(command: list[str], cache: str) -> list[float]:
  """Runs `mjx-hopper` `command` in a fresh process on compile cache folder `cache`. Returns the
  seconds from process start at which it printed each `[eval]` line."""
  env = dict(ENVIRON, MJX_HOPPER_JAX_CACHE=cache, PYTHONUNBUFFERED="1")
  start = time.perf_counter()
  proc = subprocess.Popen([sys.executable, "-P", "-m", "mjx_hopper.faces.cli", *command], env=env,
                          text=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
  lines = [(time.perf_counter() - start, line) for line in proc.stdout]
  if proc.wait():
    raise SystemExit(f"time_to_score: the run failed (exit {proc.returncode}):\n"
                     + "".join(line for _, line in lines)[-3000:])
  return [t for t, line in lines if line.startswith("[eval]")]


def on_process_clock(rows: list[dict], eval_times: list[float]) -> list[dict]:
  """A run's evaluations (log.csv's, on the run's own clock) with `wall_s` the seconds from
  process start at which each was printed (`run_wall_s`: the run's clock)."""
  if len(rows) != len(eval_times):
    raise SystemExit(f"time_to_score: log.csv holds {len(rows)} evaluations and the run printed "
                     f"{len(eval_times)}")
  return [{**r, "wall_s": t, "run_wall_s": r["wall_s"]} for r, t in zip(rows, eval_times)]


def main() -> None:
  p = common.parser(__doc__)
  p.add_argument("robot", help="a robot, or a task of your own as module:Class")
  p.add_argument("--kind", default="gpu", help="the robot preset: gpu or cpu")
  p.add_argument("--agent", default=None,
                 help="another agent than the preset's: its own defaults of --kind's name, with "
                 "the trainer's default layout (as `mjx-hopper train --agent`)")
  p.add_argument("--seeds", default="100,101,102", help="held out: the presets were tuned on 0-9")
  p.add_argument("--minutes", type=float, default=None,
                 help="wall-clock budget (default: the preset's)")
  p.add_argument("--target", type=float, default=None, help="default: the preset's")
  p.add_argument("--run-on", action="store_true",
                 help="run out the budget instead of stopping once every seed reached the target")
  p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                 help="an agent setting replacing the preset's")
  p.add_argument("--train-set", action="append", default=[], metavar="NAME=VALUE",
                 help="a setting of the trainer's layout replacing the preset's, e.g. "
                 "batch_size=32768 (passed as `mjx-hopper train --batch-size 32768`)")
  p.add_argument("--cache", choices=("cold", "warm"), default="cold",
                 help="cold: each seed on an empty compile cache; warm: on a cache that a run "
                 "of the same configuration filled first")
  p.add_argument("--physics", default="mjx", help="the physics engine (`mjx-hopper train "
                 "--physics`): mjx or c")
  p.add_argument("--cpu-devices", type=int, default=os.cpu_count() or 1)
  p.add_argument("--out", default=None, help="default: runs/time_to_score/ROBOT_KIND")
  p.add_argument("--label", default="", help="results: time_to_score_ROBOT_KIND_LABEL.json")
  p.add_argument("--render-only", metavar="OUT", default=None,
                 help="only render OUT/episode.npz to frame.png and robot.gif")
  args = p.parse_args()
  import mjx_hopper
  mjx_hopper.setup(cpu_devices=args.cpu_devices)  # before MuJoCo's import (its GL), for rendering
  if args.render_only:
    print("\n".join(render(args.render_only)))
    return
  import jax

  from mjx_hopper.settings.training import TrainConfig
  from mjx_hopper.settings import flags, presets
  try:
    preset = presets.get(args.robot, args.kind)
  except ValueError as error:
    raise SystemExit(f"time_to_score: {error}")
  agent = args.agent or preset.agent
  target = preset.target if args.target is None else args.target
  minutes = preset.minutes if args.minutes is None else args.minutes
  name = args.robot.split(":")[-1]
  out = args.out or os.path.join("runs", "time_to_score", f"{name}_{args.kind}")
  seeds = [int(s) for s in args.seeds.split(",")]
  layout = flags.overrides(args.train_set, "--train-set")
  for setting in layout:
    if setting not in {f.name for owner, f in flags.fields() if owner is TrainConfig}:
      raise SystemExit(f"time_to_score: --train-set {setting} is no setting of the trainer's "
                       "layout (`mjx-hopper train --help` lists them)")
  for seed in seeds:  # a run there would resume, and its times would mean nothing
    if os.path.exists(os.path.join(out, f"seed_{seed}", "checkpoints")):
      raise SystemExit(f"time_to_score: {out}/seed_{seed} already holds a run; choose another "
                       "--out or remove it")

  def command(seed: int, out_dir: str, minutes: float = minutes) -> list[str]:
    sets = [a for s in args.set for a in ("--set", s)]
    sets += [a for name, value in layout.items() for a in ("--" + name.replace("_", "-"),
                                                           str(value))]
    return ["--cpu-devices", str(args.cpu_devices), "train", "--env", args.robot, "--preset",
            args.kind, "--agent", agent, "--physics", args.physics, *sets, "--seed", str(seed),
            "--total-env-steps",
            str(10**12), "--max-minutes", str(minutes), "--no-progress", "--out-dir", out_dir,
            *([] if args.run_on else ["--stop-at-return", str(target)])]

  results = {}
  with tempfile.TemporaryDirectory(prefix="time_to_score_") as caches:
    if args.cache == "warm":  # filled by the same configuration, then every seed loads from it
      with tempfile.TemporaryDirectory() as fill:
        train_in_a_process(command(seeds[0] - 1, fill, minutes=1), os.path.join(caches, "warm"))
    for seed in seeds:
      cache = os.path.join(caches, "warm" if args.cache == "warm" else f"cold_{seed}")
      if args.cache == "cold" and os.path.exists(cache) and os.listdir(cache):
        raise SystemExit(f"time_to_score: the cold cache {cache} is not empty")
      out_dir = os.path.join(out, f"seed_{seed}")
      eval_times = train_in_a_process(command(seed, out_dir), cache)
      rows = on_process_clock(common.evaluations(os.path.join(out_dir, "log.csv"))[0],
                              eval_times)
      results[seed] = summarise(rows, target)
      hit = results[seed]["target_wall_s"]
      print(f"seed {seed}: {target:g} {'not reached' if hit is None else f'at {hit:.0f} s'} "
            f"from process start, best return {results[seed]['best_return']:,.0f}", flush=True)
  cfg = presets.agent_run_config(args.robot, args.kind, agent, physics=args.physics,
                                 agent_overrides=flags.overrides(args.set))  # the runs' config
  cfg = dataclasses.replace(cfg, train=dataclasses.replace(cfg.train, **layout))
  best = max(results, key=lambda s: results[s]["final_return"])
  episode = record_episode(os.path.join(out, f"seed_{best}", "checkpoints"), 0,
                           os.path.join(out, "episode.npz"))
  device = jax.local_devices()[0]
  label = f"_{args.label}" if args.label else ""
  common.write_results(f"time_to_score_{name}_{args.kind}{label}", {
      "method": METHOD.format(cache=args.cache),
      "robot": args.robot, "episode_steps": cfg.episode_steps, "kind": args.kind,
      "physics": cfg.physics,
      "target": target, "minutes": minutes, "agent": cfg.agent,
      "agent_defaults": cfg.agent_defaults,
      "agent_overrides": cfg.agent_overrides, "train": dataclasses.asdict(cfg.train),
      "eval_episodes": cfg.eval_episodes, "device": f"{device.platform} {device.device_kind}",
      "best_seed": best, "best_seed_episode": episode, "seeds": results})
  try:
    print("\n".join(render(out)))
  except Exception as error:  # no renderer here: episode.npz keeps the episode for later
    print(f"not rendered ({type(error).__name__}: {error}); run with --render-only {out}")


if __name__ == "__main__":
  main()
