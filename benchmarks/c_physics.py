"""C physics: the Hopper with its physics run by MuJoCo C (`physics="c"`, envs/mujoco_c.py:
`mujoco.batch` on threads, called from the compiled program) beside MJX's, on the CPU.
For each, a program of U env steps of B auto-resetting envs (`rollout.make_stepper`, as
env_throughput.py times it), in a fresh process split into XLA CPU devices with an empty compile
cache: its trace, lower and XLA compile seconds, and its env steps/s. Then the C path's
observations against MJX's after 1 and 100 env steps from the same resets and actions (beside
MJX against itself with the actions moved by 1e-6), and both against PyBullet's recorded outputs
(tests/oracle/) as tests/test_observation.py and tests/test_episodes.py compare them. Last,
MuJoCo C's physics alone (env_throughput.py's `mujoco.rollout` row) at each B.

    python benchmarks/c_physics.py            # 2 devices (C: a thread each), B 256, 512, 1024
"""

from __future__ import annotations

import os
import statistics
import sys
import tempfile
import time

import common

# tests/test_episodes.py's tolerances for the Hopper's episode statistics: (relative, absolute).
EPISODE_TOLERANCE = {"length": (0.25, 1.0), "return": (0.15, 2.0), "alive": (0.0, 0.05),
                     "progress": (0.0, 0.2), "electricity_cost": (0.15, 0.02),
                     "joints_at_limit_cost": (0.0, 0.05), "feet_collision_cost": (0.0, 1e-9)}


def make_env(engine: str):
  from mjx_hopper import envs
  return envs.Hopper(physics="mjx" if engine == "MJX" else "c")


def program_row(args) -> dict:
  """args.engine's program of U steps of args.batch envs: compile seconds and env steps/s."""
  import mjx_hopper
  with tempfile.TemporaryDirectory() as cache:
    mjx_hopper.setup(compile_cache=cache)  # empty: every program compiles
    import jax

    from mjx_hopper.core import rollout
    from mjx_hopper.envs import mujoco_c

    devices = len(jax.devices())
    env = make_env(args.engine)
    steps = max(20, min(1000, args.steps_total // args.batch))
    init, run = rollout.make_stepper(env, args.batch, steps)
    key = jax.random.PRNGKey(0)
    state = init(key)
    t0 = time.perf_counter()
    traced = run.trace(state, key)
    t1 = time.perf_counter()
    lowered = traced.lower()
    t2 = time.perf_counter()
    compiled = lowered.compile()
    t3 = time.perf_counter()
    state, _ = jax.block_until_ready(compiled(state, key))  # warm-up
    seconds = []
    for _ in range(3):
      start = time.perf_counter()
      state, _ = jax.block_until_ready(compiled(state, key))
      seconds.append(time.perf_counter() - start)
    rate = args.batch * steps / statistics.median(seconds)
  row = {"engine": args.engine, "devices": devices, "c_threads_per_device": (
             mujoco_c.threads_per_call() if args.engine != "MJX" else None), "batch": args.batch,
         "steps": steps,
         "trace_s": t1 - t0, "lower_s": t2 - t1, "compile_s": t3 - t2,
         "env_steps_per_s": rate}
  print(f"  {args.engine} batch {args.batch}: trace {row['trace_s']:.1f} s, lower "
        f"{row['lower_s']:.1f} s, compile {row['compile_s']:.1f} s; {rate:,.0f} env steps/s",
        file=sys.stderr, flush=True)
  return row


def agreement(args) -> dict:
  """The C path's observations against MJX's after 1 and args.agree_steps env steps of
  args.agree_batch envs from the same resets and random actions (no auto-reset); then both
  against PyBullet's recorded outputs as tests/test_observation.py and tests/test_episodes.py
  compare them."""
  import mjx_hopper
  with tempfile.TemporaryDirectory() as cache:
    mjx_hopper.setup(compile_cache=cache)
    import jax
    import jax.numpy as jnp
    import numpy as np

    from mjx_hopper.core import rollout

    envs = {e: make_env(e) for e in ("MJX", "C")}
    n, t = args.agree_batch, args.agree_steps
    keys = jax.random.split(jax.random.PRNGKey(1), n)
    actions = jax.random.uniform(jax.random.PRNGKey(2), (t, n, 3), minval=-1.0, maxval=1.0)

    def episodes(env):
      """A program: the resets' observations, then each step's observations and dones."""
      def one(state, action):
        state = jax.vmap(env.step)(state, action)
        return state, (state.obs, state.done)

      def run(actions):
        first = jax.vmap(env.reset)(keys)
        return first.obs, jax.lax.scan(one, first, actions)[1]
      return jax.jit(run)

    def compare(a, b):
      """How far episodes `a` and `b`, each (obs (t, n, O), done (t, n)), are apart."""
      diff = np.abs(a[0] - b[0])
      diff[..., 6] = np.pi - np.abs(diff[..., 6] - np.pi)  # roll, which wraps at +-pi
      diff = diff.max(axis=2)  # (t, n): each env's largest difference
      ends = lambda done: np.where(done.any(0), done.argmax(0), t)  # each env's first done
      # Steps up to the one that ends the episode in either: the robot still up.
      alive = (np.cumsum(a[1], 0) - a[1] == 0) & (np.cumsum(b[1], 0) - b[1] == 0)
      return {"obs_max_abs_diff_after_1": float(diff[0].max()),
              f"obs_max_abs_diff_after_{t}": float(diff[-1].max()),
              f"obs_median_env_max_abs_diff_after_{t}": float(np.median(diff[-1])),
              "obs_max_abs_diff_alive": float(diff[alive].max()),
              "obs_median_env_max_abs_diff_alive": float(np.median(
                  np.where(alive, diff, 0).max(axis=0))),
              "median_steps_alive": float(np.median(alive.sum(0))),
              "envs_ending_at_the_same_step": float(np.mean(ends(a[1]) == ends(b[1])))}

    mjx_run = episodes(envs["MJX"])
    reset_m, mjx = jax.device_get(mjx_run(actions))
    reset_c, c = jax.device_get(episodes(envs["C"])(actions))
    # MJX against itself with every action moved by 1e-6: how far t steps carry a tiny change.
    _, nudged = jax.device_get(mjx_run(actions + 1e-6))
    figures = {"envs": n, "steps": t,
               "reset_obs_max_abs_diff": float(np.abs(reset_c - reset_m).max()),
               "C_vs_MJX": compare(c, mjx), "MJX_vs_MJX_actions_moved_1e-6": compare(nudged, mjx)}

    # tests/test_observation.py's checks: the observation at 10 random states (the C path's
    # kinematics), and after one step from Bullet's airborne states (seed 2).
    with np.load(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests",
                              "oracle", "Hopper.npz")) as oracle:
      bullet = {k: oracle[k] for k in oracle.files if k != "meta"}
    speed = np.zeros(envs["MJX"].observation_size, bool)
    speed[3:6] = True
    for name, env in envs.items():
      init, step = jax.jit(env.init_state), jax.jit(env.step)
      states = max(float(np.abs(init(qpos, qvel).obs - obs).max()) for qpos, qvel, obs in zip(
          bullet["random_qpos"], bullet["random_qvel"], bullet["random_obs"]))
      errors = {"obs": 0.0, "speed": 0.0, "progress": 0.0}
      progress_ok = True
      for qpos, qvel, action, bullet_obs, bullet_progress in zip(
          *(bullet[f"step2_{k}"] for k in ("qpos", "qvel", "action", "obs", "progress"))):
        state = jax.device_get(step(init(qpos, qvel), jnp.asarray(action, jnp.float32)))
        miss = np.abs(np.asarray(state.obs) - bullet_obs)
        errors["obs"] = max(errors["obs"], float(miss[~speed].max()))
        errors["speed"] = max(errors["speed"], float(miss[speed].max()))
        progress = abs(float(state.metrics["progress"]) - float(bullet_progress))
        errors["progress"] = max(errors["progress"], progress)
        progress_ok &= progress <= max(0.02 * abs(float(bullet_progress)), 0.02)
      figures[f"oracle_{name}"] = {
          "random_states_obs_max_abs_err": states, "random_states_pass": states <= 5e-5,
          "one_step_states": len(bullet["step2_obs"]),
          **{f"one_step_max_abs_err_{k}": v for k, v in errors.items()},
          # a planar robot's tolerances
          "one_step_pass": bool(errors["obs"] <= 0.01 and errors["speed"] <= 0.05
                                and progress_ok)}

    # tests/test_episodes.py's episode statistics under random and zero actions, which contacts
    # shape, as it computes them (128 episodes against Bullet's recorded ones).
    random = rollout.random_policy(envs["MJX"].action_size)
    for name, env in envs.items():
      run = jax.jit(lambda key, scale, env=env: rollout.episodes(
          env, lambda obs, k: scale * random(obs, k), key, 128))
      passed, stats = True, {}
      for policy, scale in (("random", 1.0), ("zero", 0.0)):
        ours = jax.device_get(run(jax.random.PRNGKey(1), scale))
        for stat, (rel, atol) in EPISODE_TOLERANCE.items():
          b, m = bullet[f"{policy}_{stat}"], ours[stat]
          noise = 3 * np.sqrt(b.var() / b.size + m.var() / m.size)
          allowed = max(rel * abs(b.mean()), atol) + noise
          stats[f"{policy}_{stat}"] = {"ours": float(m.mean()), "bullet": float(b.mean()),
                                       "allowed": float(allowed)}
          passed &= bool(abs(m.mean() - b.mean()) <= allowed)
      figures[f"oracle_{name}"].update(episode_statistics=stats, episode_statistics_pass=passed)
  print(f"  agreement: {figures}", file=sys.stderr, flush=True)
  return figures


def work(args):
  return agreement(args) if args.task == "agreement" else program_row(args)


def main() -> None:
  p = common.parser(__doc__)
  p.add_argument("--batches", default="256,512,1024",
                 help="B: 512 is the cpu preset's num_envs")
  p.add_argument("--devices", type=int, default=2, help="XLA CPU devices")
  p.add_argument("--threads", type=int, default=2,
                 help="MuJoCo C's threads in the rows of the physics alone (the env shares "
                 "the cores out between the devices)")
  p.add_argument("--steps-total", type=int, default=100_000,
                 help="env steps per timed call, roughly (U = this / B)")
  p.add_argument("--agree-batch", type=int, default=256)
  p.add_argument("--agree-steps", type=int, default=100)
  p.add_argument("--label", default="cpu", help="results: benchmarks/results/c_physics_LABEL.json")
  args = common.parse(p, work)
  rows = []
  for batch in map(int, args.batches.split(",")):
    for engine in ("MJX", "C"):  # one after the other, under the machine's same load
      row = common.worker(__file__, dict(vars(args), task="program", engine=engine,
                                         batch=batch), args.devices, gpus=False)
      if row is None:
        raise SystemExit(1)
      rows.append(row)
  figures = common.worker(__file__, dict(vars(args), task="agreement"), args.devices,
                          gpus=False)
  if figures is None:
    raise SystemExit(1)
  os.environ["JAX_PLATFORMS"] = "cpu"
  import env_throughput
  for batch in map(int, args.batches.split(",")):
    row = env_throughput.mujoco_c_row("Hopper", threads=args.threads, batch=batch)
    rows.append(dict(row, engine="MuJoCo C physics alone (mujoco.rollout)",
                     c_threads=args.threads))
    print(f"  {rows[-1]['engine']} batch {batch}: {row['env_steps_per_s']:,.0f} env steps/s",
          file=sys.stderr, flush=True)
  common.write_results(f"c_physics_{args.label}", {"rows": rows, "agreement": figures})


if __name__ == "__main__":
  main()
