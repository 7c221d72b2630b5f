"""PyBullet's own locomotion envs, the reference of the tests and benchmarks.

Needs the oracle extra (pybullet and gym); tests/record_oracle.py, tests/test_oracle.py and the
benchmarks use it, the runtime and the rest of the suite never.
"""

import contextlib
import ctypes
import importlib.util
import io
import os
import sys
import types

import numpy as np

BULLET_IDS = {"Hopper": "HopperBulletEnv", "Walker2D": "Walker2DBulletEnv",
              "HalfCheetah": "HalfCheetahBulletEnv", "Ant": "AntBulletEnv",
              "Humanoid": "HumanoidBulletEnv"}


@contextlib.contextmanager
def quiet():
  """Silences stdout and stderr, also what PyBullet's C code prints ("argv[0]=", its build)."""
  sys.stdout.flush()
  sys.stderr.flush()
  saved = [os.dup(1), os.dup(2)]
  devnull = os.open(os.devnull, os.O_WRONLY)
  try:
    os.dup2(devnull, 1)
    os.dup2(devnull, 2)
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
      yield
  finally:
    ctypes.CDLL(None).fflush(None)  # C's buffered output, before the streams come back
    os.dup2(saved[0], 1)
    os.dup2(saved[1], 2)
    for fd in saved + [devnull]:
      os.close(fd)


def _import_locomotion_envs():
  # pybullet_envs/__init__.py registers into gym's old registry, which gym 0.26 lacks; the env
  # modules need only gym.Env and gym.spaces, so the package is entered without its __init__.
  if "pybullet_envs.gym_locomotion_envs" not in sys.modules:
    spec = importlib.util.find_spec("pybullet_envs")
    if spec is None:
      raise ImportError("PyBullet is not installed: pip install -e '.[oracle]' (Python 3.11)")
    package = types.ModuleType("pybullet_envs")
    package.__path__ = list(spec.submodule_search_locations)
    sys.modules.setdefault("pybullet_envs", package)
    with quiet():
      import gym  # noqa: F401  (prints a deprecation banner)
      from pybullet_envs import gym_locomotion_envs  # noqa: F401  (pybullet prints its build)
  return sys.modules["pybullet_envs.gym_locomotion_envs"]


def make(env_id: str, seed: int = 0):
  """PyBullet's env for one of our ids, reset once with `seed`."""
  module = _import_locomotion_envs()
  with quiet():
    env = getattr(module, BULLET_IDS[env_id])()
    env.seed(seed)
    env.reset()
  return env


def link_masses(env) -> dict[str, float]:
  """Bullet's mass of each robot part that has one (kg), by name."""
  client = env._p
  masses = {}
  for name, part in env.robot.parts.items():
    mass = client.getDynamicsInfo(part.bodies[part.bodyIndex], part.bodyPartIndex)[0]
    if mass > 0:
      masses[name] = mass
  return masses


def set_state(env, ours, qpos, qvel) -> np.ndarray:
  """Puts Bullet's robot in our env's state `qpos` (nq,), `qvel` (nv,); returns its observation.

  A planar root maps to Bullet's first three joints, a free root to Bullet's base (the torso's
  centre of mass); other joints go by name.
  """
  import mujoco
  model = ours.mj_model
  qpos, qvel = np.asarray(qpos, np.float64), np.asarray(qvel, np.float64)
  client, body = env._p, env.robot.objects[0]
  index = {client.getJointInfo(body, j)[1].decode(): j for j in range(client.getNumJoints(body))}
  for j in range(model.njnt):
    q, v = model.jnt_qposadr[j], model.jnt_dofadr[j]
    if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE:
      rot = np.zeros(9)
      mujoco.mju_quat2Mat(rot, qpos[q + 3:q + 7])
      rot = rot.reshape(3, 3)
      com = rot @ model.body_ipos[model.jnt_bodyid[j]]
      w, x, y, z = qpos[q + 3:q + 7]
      client.resetBasePositionAndOrientation(body, qpos[q:q + 3] + com, [x, y, z, w])
      angular = rot @ qvel[v + 3:v + 6]
      client.resetBaseVelocity(body, qvel[v:v + 3] + np.cross(angular, com), angular)
    else:
      name = model.joint(j).name
      bullet_joint = j if model.jnt_bodyid[j] == model.body(ours.torso).id else index[name]
      client.resetJointState(body, bullet_joint, qpos[q], qvel[v])
  # calc_state reports the foot contacts found by Bullet's last step; a state set by hand has
  # had no step, so its contacts are those of a fresh reset, not of an earlier episode.
  env.robot.feet_contact[:] = 0.0
  return env.robot.calc_state()


TERMS = ("alive", "progress", "electricity_cost", "joints_at_limit_cost", "feet_collision_cost")


def run_episodes(env, n_episodes: int, policy: str, seed: int,
                 first: dict[str, list] | None = None) -> dict[str, np.ndarray]:
  """Per-episode length, return and mean reward terms (TERMS) of 'random' or 'zero' actions.
  With `first` ({"actions", "obs", "terms", "done"} of empty lists), episode 0 is also recorded
  there: its first observation, then each step's action, observation, terms and done."""
  rng = np.random.default_rng(seed)
  out = {"length": [], "return": [], **{n: [] for n in TERMS}}
  act_size = env.action_space.shape[0]
  for episode in range(n_episodes):
    with quiet():
      obs = env.reset()
    record = first if episode == 0 else None
    if record is not None:
      record["obs"].append(obs)
    terms, total, done, t = [], 0.0, False, 0
    while not done and t < 1000:
      a = rng.uniform(-1, 1, act_size) if policy == "random" else np.zeros(act_size)
      obs, r, done, _ = env.step(a)
      terms.append(env.rewards)
      total += r
      t += 1
      if record is not None:
        for k, v in zip(("actions", "obs", "terms", "done"), (a, obs, env.rewards, done)):
          record[k].append(v)
    out["length"].append(t)
    out["return"].append(total)
    for name, column in zip(TERMS, np.array(terms).T):
      out[name].append(column.mean())
  return {k: np.array(v) for k, v in out.items()}
