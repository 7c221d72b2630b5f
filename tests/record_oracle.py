"""Records what PyBullet computes for each robot into tests/oracle/ROBOT.npz, the data that the
fidelity tests compare our envs with: model facts, observations at reset, at random states and
after one step, and the episodes of fixed action sequences (observations, reward terms and
terminations). Each file records how it was made (its `meta`: command, versions, date, seeds).

    pip install -e '.[oracle]'    # PyBullet 3.2.7's wheels are for Python 3.11
    python tests/record_oracle.py [--robots Hopper,Ant] [--out tests/oracle]
"""

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
from importlib.metadata import version

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import pybullet_oracle  # noqa: E402

ROBOTS = ("Hopper", "Walker2D", "HalfCheetah", "Ant", "Humanoid")
OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "oracle")
RESET_SEEDS = (0, 1, 2)
RANDOM_STATES = dict(seed=1, count=10)
# One control step from airborne states: (rng seed, count) per robot; the Humanoid's second set
# is tests/test_observation.py's armature test.
ONE_STEPS = {robot: ((2, 2),) for robot in ROBOTS} | {"Humanoid": ((2, 2), (3, 4))}
EPISODES = {"random": 30, "zero": 10}
# HalfCheetah's and Ant's random episodes run to 1,000 and about 800 steps (the others' to
# 12-20), so their per-step means vary little from episode to episode: 10 episodes measure them.
FEWER_EPISODES = {("HalfCheetah", "random"): 10, ("Ant", "random"): 10}
EPISODE_SEED = 0  # of the actions, and of PyBullet's resets
QUATERNIONS = dict(seed=0, count=200)


def random_state(env, rng, airborne=False):
  """qpos, qvel with every joint inside its limits (in the middle half of its range when
  airborne, so that no limit is reached within a step), a perturbed root, random speeds."""
  model = env.mj_model
  qpos = np.array(model.qpos0)
  limits = model.jnt_range[[model.joint(j).id for j in env.joints]]
  middle, half = limits.mean(1), (limits[:, 1] - limits[:, 0]) / 2
  spread = 0.5 if airborne else 1.0
  qpos[env._qadr] = rng.uniform(middle - spread * half, middle + spread * half)
  if env._root == "planar":
    qpos[:3] += rng.uniform(-0.3, 0.3, 3)
    qpos[1] += 0.6 if airborne else 0.0
  else:
    qpos[:3] += rng.uniform(-0.3, 0.3, 3) + (0.0, 0.0, 0.6 if airborne else 0.0)
    quat = rng.normal(size=4) * [3, 0.3, 0.3, 0.3]  # mostly upright, any heading
    qpos[3:7] = quat / np.linalg.norm(quat)
  return qpos, rng.uniform(-2, 2, model.nv) * (0.5 if airborne else 1.0)


def model_facts(env, bullet) -> dict:
  """Masses, inertias, joints, limits, torques, timing, feet and specs, as Bullet has them."""
  client, robot = bullet._p, bullet.robot
  parts, masses, inertias = [], [], []
  for name, part in robot.parts.items():
    info = client.getDynamicsInfo(part.bodies[part.bodyIndex], part.bodyPartIndex)
    if info[0] > 0:
      parts.append(name)
      masses.append(info[0])
      inertias.append(info[2])
  joints = robot.ordered_joints
  # What apply_action multiplies by: the Humanoid's own motor_power list, else power_coef.
  coefs = getattr(robot, "motor_power", [j.power_coef for j in joints])
  return {"parts": np.array(parts), "masses": np.array(masses), "inertias": np.array(inertias),
          "part_count": len(robot.parts), "joints": np.array([j.joint_name for j in joints]),
          "joint_limits": np.array([(j.lowerLimit, j.upperLimit) for j in joints]),
          "torques": robot.power * np.array(coefs, float), "dt": bullet.scene.dt,
          "frame_skip": bullet.scene.frame_skip, "feet": np.array(robot.foot_list),
          "initial_z": robot.initial_z, "electricity_cost": bullet.electricity_cost,
          "stall_torque_cost": bullet.stall_torque_cost,
          "action_size": bullet.action_space.shape[0],
          "observation_size": bullet.observation_space.shape[0]}


def mass_matrices(env, bullet, seed=0, count=3) -> dict:
  """Bullet's joint-space mass matrix at `count` random joint angles (the root at rest pose)."""
  model = env.mj_model
  rng = np.random.default_rng(seed)
  pybullet_oracle.set_state(bullet, env, model.qpos0, np.zeros(model.nv))
  free = env._root == "free"
  qposes, matrices = [], []
  for _ in range(count):
    qpos = np.array(model.qpos0)
    qpos[env._qadr] = rng.uniform(-0.5, 0.5, env.action_size)
    if not free:
      qpos[:3] = rng.uniform(-0.5, 0.5, 3)
    joint_angles = qpos[7:] if free else qpos  # Bullet takes no base coordinates
    qposes.append(qpos)
    with pybullet_oracle.quiet():  # Bullet warns of its own non-unit joint axes
      matrices.append(bullet._p.calculateMassMatrix(bullet.robot.objects[0], list(joint_angles)))
  return {"mass_matrix_qpos": np.array(qposes), "mass_matrix": np.array(matrices)}


def resets(env, bullet) -> dict:
  """Bullet's observation after reset with each of RESET_SEEDS, and its joints' positions."""
  positions, observations = [], []
  for seed in RESET_SEEDS:
    bullet.seed(seed)
    with pybullet_oracle.quiet():
      observations.append(bullet.reset())
    positions.append([j.get_position() for j in bullet.robot.ordered_joints])
  return {"reset_joint_positions": np.array(positions), "reset_obs": np.array(observations)}


def random_states(env, bullet) -> dict:
  """Bullet's observation, torso position and speed, and parts' positions at random states."""
  rng = np.random.default_rng(RANDOM_STATES["seed"])
  parts = list(pybullet_oracle.link_masses(bullet))
  out = {k: [] for k in ("qpos", "qvel", "obs", "body_xyz", "torso_speed", "part_xyz")}
  for _ in range(RANDOM_STATES["count"]):
    qpos, qvel = random_state(env, rng)
    out["obs"].append(pybullet_oracle.set_state(bullet, env, qpos, qvel))
    out["qpos"].append(qpos)
    out["qvel"].append(qvel)
    out["body_xyz"].append(bullet.robot.body_xyz)
    out["torso_speed"].append(bullet.robot_body.speed())
    out["part_xyz"].append([bullet.robot.parts[name].pose().xyz() for name in parts])
  return {f"random_{k}": np.array(v) for k, v in out.items()}


def one_steps(env, bullet, seed, count) -> dict:
  """From `count` random airborne states, Bullet's observation after one control step of a
  random action (scaled by 0.3), and its progress term."""
  rng = np.random.default_rng(seed)
  out = {k: [] for k in ("qpos", "qvel", "action", "obs", "progress")}
  for _ in range(count):
    qpos, qvel = random_state(env, rng, airborne=True)
    action = rng.uniform(-1, 1, env.action_size) * 0.3
    pybullet_oracle.set_state(bullet, env, qpos, qvel)
    bullet.potential = bullet.robot.calc_potential()
    obs, _, _, _ = bullet.step(action)
    for k, v in zip(out, (qpos, qvel, action, obs, bullet.rewards[1])):
      out[k].append(v)
  return {f"step{seed}_{k}": np.array(v) for k, v in out.items()}


def episodes(robot, policy) -> dict:
  """Per-episode length, return and mean reward terms of 'random' or 'zero' actions, from a
  fresh env seeded EPISODE_SEED; and episode 0's actions, observations, terms and dones."""
  env = pybullet_oracle.make(robot, seed=EPISODE_SEED)
  trajectory = {"actions": [], "obs": [], "terms": [], "done": []}
  stats = pybullet_oracle.run_episodes(env, FEWER_EPISODES.get((robot, policy), EPISODES[policy]),
                                       policy, EPISODE_SEED, first=trajectory)
  dtypes = {"actions": np.float32, "obs": np.float32, "terms": np.float32, "done": bool}
  return ({f"{policy}_{k}": v for k, v in stats.items()}
          | {f"{policy}_episode0_{k}": np.array(v, dtypes[k]) for k, v in trajectory.items()})


def record(robot: str) -> dict[str, np.ndarray]:
  """Everything the tests compare for `robot`, as Bullet computes it (no metadata)."""
  from mjx_hopper import envs
  env, bullet = envs.make(robot), pybullet_oracle.make(robot)
  data = model_facts(env, bullet) | mass_matrices(env, bullet) | resets(env, bullet)
  data |= random_states(env, bullet)
  for seed, count in ONE_STEPS[robot]:
    data |= one_steps(env, bullet, seed, count)
  for policy in EPISODES:
    data |= episodes(robot, policy)
  return {k: np.asarray(v) for k, v in data.items()}


def euler_angles() -> dict[str, np.ndarray]:
  """pybullet.getEulerFromQuaternion of random unit quaternions (w, x, y, z)."""
  import pybullet
  rng = np.random.default_rng(QUATERNIONS["seed"])
  quats = rng.normal(size=(QUATERNIONS["count"], 4))
  quats /= np.linalg.norm(quats, axis=1, keepdims=True)
  rpy = [pybullet.getEulerFromQuaternion([x, y, z, w]) for w, x, y, z in quats]
  return {"quats": quats, "rpy": np.array(rpy)}


def meta() -> dict:
  """How the data was made: the command, the versions, the date, the commit and the seeds."""
  root = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
  commit = subprocess.run(["git", "-C", root, "rev-parse", "HEAD"], capture_output=True,
                          text=True).stdout.strip()
  return {"command": " ".join(["python", *sys.argv]), "pybullet": version("pybullet"),
          "mujoco": version("mujoco"), "python": platform.python_version(),
          "machine": platform.machine(), "date": datetime.date.today().isoformat(),
          "commit": commit, "reset_seeds": RESET_SEEDS, "random_states": RANDOM_STATES,
          "one_steps": ONE_STEPS, "episodes": EPISODES,
          "fewer_episodes": {"/".join(k): v for k, v in FEWER_EPISODES.items()},
          "episode_seed": EPISODE_SEED, "quaternions": QUATERNIONS}


def main() -> None:
  p = argparse.ArgumentParser(description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
  p.add_argument("--robots", default=",".join(ROBOTS))
  p.add_argument("--out", default=OUT)
  args = p.parse_args()
  robots = args.robots.split(",")
  unknown = sorted(set(robots) - set(ROBOTS))
  if unknown:
    p.error(f"--robots names {unknown}; the robots are {list(ROBOTS)}")
  os.makedirs(args.out, exist_ok=True)
  made = json.dumps(meta())
  files = {robot: lambda robot=robot: record(robot) for robot in robots}
  files["euler"] = euler_angles
  for name, make in files.items():
    path = os.path.join(args.out, f"{name}.npz")
    np.savez_compressed(path, meta=np.array(made), **make())
    print(f"{path}: {os.path.getsize(path) / 1e3:.0f} kB")


if __name__ == "__main__":
  main()
