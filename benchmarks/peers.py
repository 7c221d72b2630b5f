"""Peers: our D4PG beside Brax's SAC and PPO on our Hopper, one after another, each run a process
alone on the GPU; or, with --cpu-baseline MINUTES, SB3's SAC with
rl-baselines3-zoo's HopperBulletEnv-v0 settings on PyBullet, then our D4PG cpu preset, MINUTES
each, on the CPU (the `peers` extra). Evaluations: 16 deterministic 1,000-step episodes of our
Hopper (SB3's on PyBullet, and on ours at the end), each run timed from its process's start,
evaluations included, and stopped at the same minutes. Results:
benchmarks/results/peers_LABEL.json, with every curve.

--grid TRAINER:NAME=V1,V2 replaces one of the settings the Brax trainers start from (BRAX);
every combination of the --grid values is a run.
"""

from __future__ import annotations

import argparse
import ast
import csv
import inspect
import itertools
import json
import os
import platform
import signal
import subprocess
import sys
import time

import common

THRESHOLDS = (1000, 2000, 2500)  # 1,000: standing through the episode (alive 1 a step)
# SEED is held out for our run (the presets were tuned on seeds 0-9); SB3's run takes it too.
EPISODE_STEPS, EVAL_EPISODES, SEED = 1000, 16, 100
# Brax's training notebook, `hopper` (SAC), and its locomotion PPO (`ant`); eval_every (env
# steps between evaluations) and num_timesteps (an upper bound: runs stop at --minutes) are ours.
BRAX = {
    "sac": dict(num_timesteps=50_000_000, eval_every=25_600, reward_scaling=30,
                normalize_observations=True, action_repeat=1, discounting=0.997,
                learning_rate=6e-4, num_envs=128, batch_size=512, grad_updates_per_step=64,
                max_devices_per_host=1, max_replay_size=1048576, min_replay_size=8192, seed=1),
    "ppo": dict(num_timesteps=1_000_000_000, eval_every=1_310_720, reward_scaling=10,
                normalize_observations=True, action_repeat=1, unroll_length=5,
                num_minibatches=32, num_updates_per_batch=4, discounting=0.97,
                learning_rate=3e-4, entropy_cost=1e-2, num_envs=4096, batch_size=2048, seed=1),
}
OURS = {"gpu": "--agent d4pg --preset gpu --eval-every 200000",
        "cpu": "--agent d4pg --preset cpu --eval-every 200000"}
# rl-baselines3-zoo, hyperparams/sac.yml: HopperBulletEnv-v0 (its pybullet defaults with a
# linear learning-rate schedule over n_timesteps).
RL_ZOO_SAC = dict(n_timesteps=1_000_000, learning_rate=7.3e-4, buffer_size=300_000,
                  batch_size=256, ent_coef="auto", gamma=0.98, tau=0.02, train_freq=8,
                  gradient_steps=8, learning_starts=10_000, use_sde=True,
                  policy_kwargs=dict(log_std_init=-3, net_arch=[400, 300]))


class Deadline(Exception):
  """Raised from a trainer's callback once a run has used its minutes."""


def brax_train(trainer: str):
  from brax.training.agents.ppo import train as ppo
  from brax.training.agents.sac import train as sac
  return {"sac": sac.train, "ppo": ppo.train}[trainer]


def parse_grid(specs: list[str]) -> list[tuple[str, dict]]:
  """(Brax trainer, settings) of every combination of the --grid values, SAC's then PPO's. A
  spec is TRAINER:NAME=V1,V2,...; values are Python literals."""
  axes = {t: [] for t in BRAX}
  for spec in specs:
    trainer, _, assignment = spec.partition(":")
    name, _, values = assignment.partition("=")
    if trainer not in BRAX or not name or not values:
      raise SystemExit(f"--grid {spec!r}: want TRAINER:NAME=V1,V2 with TRAINER one of "
                       f"{list(BRAX)}")
    known = set(inspect.signature(brax_train(trainer)).parameters) | {"eval_every"}
    if name not in known:
      raise SystemExit(f"--grid {spec!r}: {trainer} has no setting {name!r}; it has "
                       f"{sorted(known)}")
    axes[trainer].append([(name, ast.literal_eval(v)) for v in values.split(",")])
  return [(t, dict(BRAX[t], **dict(combo))) for t in BRAX
          for combo in itertools.product(*axes[t])]


def plan(args) -> list[dict]:
  """The runs, each {name, trainer, settings, minutes, limit_s: when the parent stops it}."""
  if args.cpu_baseline:
    specs = [("sb3", dict(RL_ZOO_SAC, seed=SEED)), ("ours", OURS["cpu"])]
    minutes = args.cpu_baseline
  else:
    specs = [("ours", OURS["gpu"]), *parse_grid(args.grid)]
    minutes = args.minutes
  runs = []
  for i, (trainer, settings) in enumerate(specs):
    if trainer == "ours":
      settings = settings.split() + ["--seed", str(SEED)]
    limit_s = 60 * minutes + args.grace  # every run on its process's clock
    python = args.ours_python if trainer == "ours" and args.ours_python else sys.executable
    runs.append({"name": f"{i}_{trainer}", "trainer": trainer, "settings": settings,
                 "minutes": minutes, "eval_episodes": EVAL_EPISODES, "limit_s": limit_s,
                 "python": python})
  return runs


def start(run: dict, out: str) -> subprocess.Popen:
  folder = os.path.join(out, run["name"])
  os.makedirs(folder, exist_ok=True)
  env = dict(os.environ, XLA_PYTHON_CLIENT_MEM_FRACTION="0.9",
             MJX_HOPPER_JAX_CACHE=os.path.join(out, "jax_cache"))
  run["launch_time"] = time.time()
  with open(os.path.join(folder, "run.json"), "w") as f:
    json.dump(run, f, indent=1)
  return subprocess.Popen([run["python"], __file__, "--worker", folder], env=env)


def run_all(runs: list[dict], out: str) -> None:
  """Runs one at a time, each alone on the device; a run still going limit_s after its start is
  stopped (one SIGTERM: ours saves and exits), and killed 60 s later."""
  for run in runs:
    print(f"starting {run['name']} for {run['minutes']} min", flush=True)
    proc, stopped = start(run, out), False
    while proc.poll() is None:
      late = time.time() - run["launch_time"] - run["limit_s"]
      if late > 60:
        proc.kill()
      elif late > 0 and not stopped:
        proc.send_signal(signal.SIGTERM)
        stopped = True
      time.sleep(2)
    if proc.returncode:
      print(f"{run['name']} exited with {proc.returncode}; see its output above", flush=True)


def evaluations(folder: str) -> list[dict]:
  """Every evaluation of a run so far, {EVAL_FIELDS}, wall_s counted from its process's start."""
  if os.path.exists(os.path.join(folder, "log.csv")):  # ours: mjx_hopper.run.loop's log
    offset = read_json(os.path.join(folder, "started.json"))["loop_start_s"]
    rows = common.evaluations(os.path.join(folder, "log.csv")).get(0, [])
    return [dict(r, wall_s=r["wall_s"] + offset) for r in rows]
  if not os.path.exists(os.path.join(folder, "evals.csv")):
    return []
  with open(os.path.join(folder, "evals.csv")) as f:
    return [{k: float(v) for k, v in r.items()} for r in csv.DictReader(f)]


def summarise(runs: list[dict], out: str) -> list[dict]:
  rows = []
  for run in runs:
    folder = os.path.join(out, run["name"])
    curve = evaluations(folder)
    meta = read_json(os.path.join(folder, "meta.json"))
    row = {"name": run["name"], "trainer": run["trainer"], "settings": run["settings"],
           "minutes": run["minutes"], "eval_episodes": run["eval_episodes"],
           "device": meta.get("device"), "meta": meta,
           "best_return": max((e["eval_return"] for e in curve), default=None),
           "final_return": curve[-1]["eval_return"] if curve else None,
           "env_steps": int(curve[-1]["env_steps"]) if curve else 0, "curve": curve}
    for t in THRESHOLDS:
      hit = next((e for e in curve if e["eval_return"] >= t), None)
      row[f"to_{t}"] = None if hit is None else {"wall_s": hit["wall_s"],
                                                  "env_steps": int(hit["env_steps"])}
    rows.append(row)
  return rows


def report(rows: list[dict]) -> None:
  hits = lambda r, t: f"{r[f'to_{t}']['wall_s']:.0f}" if r[f"to_{t}"] else "not reached"
  print(common.table(["run", *(f"to {t:,} (s)" for t in THRESHOLDS), "best return", "env steps"],
                     [[r["name"], *(hits(r, t) for t in THRESHOLDS), f"{r['best_return'] or 0:.0f}",
                       f"{r['env_steps']:,}"] for r in rows]))


def log_eval(folder: str, *values: float) -> None:
  """Appends an evaluation, its EVAL_FIELDS in order, to a Brax or SB3 run's evals.csv."""
  path = os.path.join(folder, "evals.csv")
  new = not os.path.exists(path)
  with open(path, "a", newline="") as f:
    writer = csv.writer(f)
    if new:
      writer.writerow(common.EVAL_FIELDS)
    writer.writerow(values)


def read_json(path: str) -> dict:
  """The dict in a JSON file, or {} when there is none."""
  if not os.path.exists(path):
    return {}
  with open(path) as f:
    return json.load(f)


def write_meta(folder: str, **meta) -> None:
  """A run's meta.json (what it ran on), written once by its worker."""
  with open(os.path.join(folder, "meta.json"), "w") as f:
    json.dump(meta, f, indent=1)


def device_put_replicated(tree, devices):
  """jax.device_put_replicated, which Brax 0.14's trainers call and jax 0.10 removed (as in
  docs/brax.md): each leaf as one array with a copy per device."""
  import jax
  import jax.numpy as jnp
  import numpy as np
  from jax.sharding import Mesh, NamedSharding, PartitionSpec
  sharding = NamedSharding(Mesh(np.array(devices), ("replica",)), PartitionSpec("replica"))
  return jax.tree.map(
      lambda x: jax.device_put(jnp.broadcast_to(x, (len(devices),) + jnp.shape(x)), sharding),
      tree)


def worker_ours(run: dict, folder: str) -> None:
  """Our agent through the project's CLI (`mjx-hopper train`); its log.csv's wall_s counts
  from the loop's start, `started.json` says how long after the process's start that was."""
  from mjx_hopper.faces import cli  # noqa: F401
  from mjx_hopper.run import loop  # noqa: F401  (loop: imported before the clock is read)
  loop_start = time.time() - run["launch_time"]
  with open(os.path.join(folder, "started.json"), "w") as f:
    json.dump({"loop_start_s": loop_start}, f)
  minutes = run["minutes"] - loop_start / 60
  cli.main(["train", *run["settings"], "--total-env-steps", str(10**10), "--max-minutes",
            str(minutes), "--eval-episodes", str(run["eval_episodes"]), "--out-dir", folder,
            "--no-progress", "--log-every", "30", "--checkpoint-minutes", "10000"])
  import jax
  write_meta(folder, device=jax.devices()[0].device_kind, jax=jax.__version__,
             python=platform.python_version())


def worker_brax(run: dict, folder: str) -> None:
  """Brax's SAC or PPO `train` on our Hopper; evaluations through its progress_fn."""
  import jax
  import brax
  import mjx_hopper
  from mjx_hopper import envs
  mjx_hopper.setup()
  jax.device_put_replicated = device_put_replicated
  write_meta(folder, device=jax.devices()[0].device_kind, jax=jax.__version__,
             brax=brax.__version__)
  settings = dict(run["settings"])
  eval_every = settings.pop("eval_every")
  deadline = 60 * run["minutes"]

  def progress(env_steps, metrics):
    wall = time.time() - run["launch_time"]
    log_eval(folder, wall, env_steps, *(float(metrics[f"eval/{k}"]) for k in (
        "episode_reward", "episode_reward_std", "avg_episode_length")))
    if wall > deadline:
      raise Deadline

  try:
    brax_train(run["trainer"])(
        environment=envs.make("Hopper", episode_steps=EPISODE_STEPS),
        episode_length=EPISODE_STEPS, num_evals=settings["num_timesteps"] // eval_every + 1,
        num_eval_envs=run["eval_episodes"], deterministic_eval=True, progress_fn=progress,
        **settings)
  except Deadline:
    pass


def bullet_hopper():
  """PyBullet's HopperBulletEnv as a gymnasium env, with gym's 1,000-step time limit."""
  import gymnasium
  import numpy as np
  pybullet_oracle = common.pybullet_oracle()

  class BulletHopper(gymnasium.Env):
    def __init__(self):
      self.env = pybullet_oracle.make("Hopper")
      self.observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (15,), np.float32)
      self.action_space = gymnasium.spaces.Box(-1.0, 1.0, (3,), np.float32)
      self.t = 0

    def reset(self, seed=None, options=None):
      super().reset(seed=seed)
      if seed is not None:
        self.env.seed(seed)
      self.t = 0
      return np.asarray(self.env.reset(), np.float32), {}

    def step(self, action):
      obs, reward, done, _ = self.env.step(action)
      self.t += 1
      return (np.asarray(obs, np.float32), float(reward), bool(done),
              self.t >= EPISODE_STEPS and not done, {})

  return BulletHopper()


def returns_on_ours(model, episodes: int, seed: int) -> list[float]:
  """The returns of `episodes` episodes of an SB3 policy (deterministic) on our Hopper, at once."""
  import jax
  import numpy as np
  from mjx_hopper import envs
  env = envs.make("Hopper", episode_steps=EPISODE_STEPS)
  step = jax.jit(jax.vmap(env.step))
  state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(seed), episodes))
  total, alive = np.zeros(episodes), np.ones(episodes, bool)
  while alive.any():
    action, _ = model.predict(np.asarray(state.obs), deterministic=True)
    state = step(state, action)
    total += alive * np.asarray(state.reward)
    alive &= np.asarray(state.done) == 0
  return total.tolist()


def worker_sb3(run: dict, folder: str) -> None:
  """SB3 SAC with rl-zoo's settings on PyBullet for `minutes` from its process's start, as our
  runs are timed (start-up and evaluations included); evaluations on PyBullet at each quarter,
  and on our Hopper at the end."""
  import numpy as np
  import stable_baselines3
  from stable_baselines3.common.callbacks import BaseCallback
  from stable_baselines3.common.evaluation import evaluate_policy
  settings = dict(run["settings"])
  total, seed = settings.pop("n_timesteps"), settings.pop("seed")
  rate = settings.pop("learning_rate")
  env, eval_env = bullet_hopper(), bullet_hopper()
  model = stable_baselines3.SAC("MlpPolicy", env, learning_rate=lambda left: left * rate,
                                seed=seed, verbose=0, **settings)
  budget, checks = 60 * run["minutes"], [0.25, 0.5, 0.75, 1.0]

  class Clock(BaseCallback):
    """Evaluates at each check of the process's clock, and stops at the last."""

    def _on_step(self):
      if time.time() - run["launch_time"] >= checks[0] * budget:
        returns, lengths = evaluate_policy(model, eval_env, run["eval_episodes"],
                                           deterministic=True, return_episode_rewards=True)
        log_eval(folder, time.time() - run["launch_time"], self.num_timesteps,
                 float(np.mean(returns)), float(np.std(returns)), float(np.mean(lengths)))
        checks.pop(0)
      return bool(checks)

  model.learn(total_timesteps=total, callback=Clock())
  ours = returns_on_ours(model, run["eval_episodes"], seed)
  final = evaluations(folder)[-1]
  write_meta(folder, device="cpu", sb3=stable_baselines3.__version__, clock="process start",
             final_return_pybullet=final["eval_return"], final_return_ours=float(np.mean(ours)),
             final_returns_ours=ours)


def main() -> None:
  p = common.parser(__doc__)
  p.add_argument("--minutes", type=float, default=8.0, help="wall-clock budget of each run")
  p.add_argument("--grid", action="append", default=[], metavar="TRAINER:NAME=V1,V2",
                 help="Brax settings to try (repeatable; every combination is a run)")
  p.add_argument("--grace", type=float, default=60.0,
                 help="seconds past --minutes before a run is stopped")
  p.add_argument("--cpu-baseline", type=float, default=None, metavar="MINUTES",
                 help="SB3 SAC on PyBullet, then our D4PG cpu preset, MINUTES each")
  p.add_argument("--ours-python", default=None, metavar="PYTHON",
                 help="the interpreter of our runs (default: this one); PyBullet, which SB3's "
                      "run needs, installs only on Python 3.11")
  p.add_argument("--label", default="run", help="results: benchmarks/results/peers_LABEL.json")
  p.add_argument("--out", default="runs/peers")
  p.add_argument("--worker", default=None, help=argparse.SUPPRESS)
  args = p.parse_args()
  if args.worker:  # one run, in a process of its own
    run = read_json(os.path.join(args.worker, "run.json"))
    workers = {"ours": worker_ours, "sac": worker_brax, "ppo": worker_brax, "sb3": worker_sb3}
    return workers[run["trainer"]](run, args.worker)
  runs = plan(args)
  os.makedirs(args.out, exist_ok=True)
  run_all(runs, args.out)
  rows = summarise(runs, args.out)
  report(rows)
  common.write_results(f"peers_{args.label}", {"thresholds": THRESHOLDS, "runs": rows})


if __name__ == "__main__":
  main()
