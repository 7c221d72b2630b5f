"""PyBullet's walker env on MuJoCo MJX, behind Brax's `Env`/`State` interface.

A robot subclass names its MJCF file, joints, feet and constants, and says when it is alive; the
observation, reward terms, termination and reset live here, with PyBullet's semantics.
"""

from __future__ import annotations

import contextlib
import functools
import inspect
import io
from typing import ClassVar

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

with contextlib.redirect_stdout(io.StringIO()):
  # mujoco.mjx prints a line at import when its optional GPU backend (warp) is absent.
  from mujoco import mjx

from brax.envs.base import Env, State
from flax import struct

from mjx_hopper.envs import model as robot_model, mujoco_c, specs

# An env's physics engines: MJX (JAX, on any device), or MuJoCo C on the host's CPU (mujoco_c).
PHYSICS = ("mjx", "c")
REWARD_TERMS = ("alive", "progress", "electricity_cost", "joints_at_limit_cost",
                "feet_collision_cost")
# Brax's EpisodeWrapper (which `brax.envs.training.wrap` and Brax's trainers add) keeps this key
# in `state.info`; under it, the wrapper owns the time limit and `info["steps"]`/"truncation".
BRAX_EPISODE_KEY = "episode_done"


@functools.partial(jax.jit, static_argnums=2)
def _physics(model: mjx.Model, data: mjx.Data, substeps: int) -> mjx.Data:
  """`substeps` MJX steps of `data` under `model`.

  Jitted on its own so that every program that steps an env reuses one trace of MJX's slow-to-
  trace step. The model is an argument so that Brax's DomainRandomizationVmapWrapper, which swaps
  `env.sys`, steps each env with its own model."""
  return jax.lax.fori_loop(0, substeps, lambda _, d: mjx.step(model, d), data)


# A reset's kinematics, traced once per model layout in the same way.
_forward_kinematics = jax.jit(mjx.kinematics)


class Robot(struct.PyTreeNode):
  """What PyBullet's robot computes in `calc_state`, for one env.

  Shapes are per env; J is the number of actuated joints and F the number of feet.
  """

  body_xyz: jax.Array       # (3,) x, y: mean position of Bullet's parts; z: torso height (m)
  body_rpy: jax.Array       # (3,) torso roll, pitch, yaw (rad)
  speed: jax.Array          # (3,) torso linear velocity in the world frame (m/s)
  joint_pos: jax.Array      # (J,) joint angles scaled to [-1, 1] between their limits
  joint_speeds: jax.Array   # (J,) 0.1 * joint velocity (rad/s), as PyBullet scales it
  feet_contact: jax.Array   # (F,) 1.0 where the foot touched the floor; one step old, as in obs


def _quat_to_mat(q: jax.Array) -> jax.Array:
  """(3, 3) rotation matrix of a (w, x, y, z) unit quaternion."""
  w, x, y, z = q
  return jnp.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                    [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                    [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def quat_to_rpy(quat: jax.Array) -> jax.Array:
  """Bullet's roll, pitch, yaw (rad) of (w, x, y, z) quaternions (extrinsic x-y-z)."""
  w, x, y, z = quat[..., 0], quat[..., 1], quat[..., 2], quat[..., 3]
  roll = jnp.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
  pitch = jnp.arcsin(jnp.clip(2 * (w * y - z * x), -1.0, 1.0))
  yaw = jnp.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
  return jnp.stack([roll, pitch, yaw], axis=-1)


class LocomotionEnv(Env):
  """A PyBullet locomotion task (WalkerBaseBulletEnv) on MuJoCo MJX.

  A robot sets the class constants and `alive_bonus`; a custom task overrides `reward` and/or
  `is_done`, and `edit_model` changes the physics. `episode_steps` is the time limit.
  `physics` is the engine that steps the task, not part of it (a run's setting, which the
  task's settings leave out): "mjx" (MJX, on any device) or "c" (MuJoCo C on the host's CPU,
  envs/mujoco_c.py), which compiles and steps faster there.
  """

  xml_file: ClassVar[str]
  joints: ClassVar[tuple[str, ...]]        # actuated joints, in action order
  power: ClassVar[float]
  power_coefs: ClassVar[tuple[float, ...]]  # torque at |a| = 1 is power * power_coef (Nm)
  feet: ClassVar[tuple[str, ...]]          # bodies whose floor contact is observed
  initial_z: ClassVar[float]               # torso height at reset (m)
  torso: ClassVar[str] = "torso"
  electricity_cost: ClassVar[float] = -2.0
  stall_torque_cost: ClassVar[float] = -0.1
  joints_at_limit_cost: ClassVar[float] = -0.1
  walk_target: ClassVar[tuple[float, float]] = (1000.0, 0.0)
  control_dt: ClassVar[float] = 0.0165
  n_substeps: ClassVar[int] = 4
  reset_noise: ClassVar[float] = 0.1
  contact_distance: ClassVar[float] = 0.005  # Bullet reports a contact within ~5 mm
  # Bodies whose geoms touch the floor; None: every body's. Leaving out parts that cannot reach
  # the floor while the robot is alive makes the step cheaper.
  floor_bodies: ClassVar[tuple[str, ...] | None] = None

  def __new__(cls, *args, **kwargs):
    env = super().__new__(cls)
    # The constructor's settings as given, which `envs.settings_of` completes with defaults: what
    # a run records of its task.
    signature = inspect.signature(cls.__init__)
    try:
      arguments = list(signature.bind(None, *args, **kwargs).arguments.items())[1:]
    except TypeError:
      arguments = []  # __init__ raises it, with its own message
    env._given_settings = {}
    for name, value in arguments:
      kind = signature.parameters[name].kind
      if kind == inspect.Parameter.VAR_KEYWORD:
        env._given_settings.update(value)
      elif kind != inspect.Parameter.VAR_POSITIONAL:
        env._given_settings[name] = value
    env._given_settings.pop("physics", None)  # how the task is stepped, not what it is
    return env

  def __init__(self, episode_steps: int = 1000, physics: str = "mjx"):
    if not isinstance(episode_steps, (int, np.integer)) or episode_steps < 1:
      raise ValueError(f"episode_steps must be an integer >= 1, got {episode_steps!r}")
    if physics not in PHYSICS:
      raise ValueError(f"physics must be one of {list(PHYSICS)}, got {physics!r}")
    self.episode_steps, self.physics = int(episode_steps), physics
    model = self.mj_model = robot_model.load(self)
    # This process's first device (under jax.distributed, MJX's default, jax.devices()[0], may
    # be another process's).
    device = jax.local_devices()[0]
    if physics == "c" and device.platform != "cpu":
      raise ValueError(f"physics='c' runs MuJoCo C on the host's CPU, between the device's "
                       f"steps; JAX runs on {device.platform} here: use physics='mjx'")
    self.mjx_model = self._own_model = mjx.put_model(model, device=device)
    joint_ids = [model.joint(n).id for n in self.joints]
    self._qadr = np.array([model.jnt_qposadr[j] for j in joint_ids])
    self._dofadr = np.array([model.jnt_dofadr[j] for j in joint_ids])
    lower, upper = model.jnt_range[joint_ids].T
    self._mid, self._half_range = (lower + upper) / 2, (upper - lower) / 2
    self._torso = model.body(self.torso).id
    self._root = robot_model.root_kind(model, self._torso, self.xml_file)
    self._parts = robot_model.bullet_parts(model)
    self._foot_geoms = robot_model.foot_geoms(model, self.feet, self.xml_file)
    # One compiled program, rather than MJX's eager one-op programs for each field.
    self._data0 = jax.jit(lambda: mjx.make_data(self.mjx_model),
                          out_shardings=jax.sharding.SingleDeviceSharding(device))()
    self._c = mujoco_c.CPhysics(model, self._data0) if physics == "c" else None

  def edit_model(self, model: mujoco.MjModel) -> None:
    """Edits the MuJoCo model before the env is built; a no-op by default."""

  def _torso_speed(self, qpos: jax.Array, qvel: jax.Array) -> jax.Array:
    """(3,) world-frame velocity of the torso's centre of mass for this qpos, qvel (m/s)."""
    com = jnp.asarray(self.mj_model.body_ipos[self._torso])  # in the torso's frame
    if self._root == "planar":
      c, s = jnp.cos(qpos[2]), jnp.sin(qpos[2])
      offset = jnp.array([c * com[0] + s * com[2], com[1], -s * com[0] + c * com[2]])
      linear = jnp.array([qvel[0], 0.0, qvel[1]])
      angular = jnp.array([0.0, qvel[2], 0.0])
    else:
      rot = _quat_to_mat(qpos[3:7])
      offset, linear, angular = rot @ com, qvel[:3], rot @ qvel[3:6]
    return linear + jnp.cross(angular, offset)

  # ---- Brax Env interface -------------------------------------------------------------------

  @property
  def observation_size(self) -> int:
    return 8 + 2 * len(self.joints) + len(self.feet)

  @property
  def action_size(self) -> int:
    return len(self.joints)

  @property
  def backend(self) -> str:
    return "mjx"

  @property
  def dt(self) -> float:
    """Seconds of simulated time per env step."""
    return self.control_dt

  @property
  def calls_host(self) -> bool:
    """Whether its step calls the host (MuJoCo C's physics): a program of it is not exported."""
    return self._c is not None

  @property
  def sys(self) -> mjx.Model:
    """The MJX model, under the name Brax's wrappers read and set."""
    return self.mjx_model

  @sys.setter
  def sys(self, model: mjx.Model) -> None:
    self.mjx_model = model

  def reset(self, rng: jax.Array) -> State:
    """A new episode: every joint at uniform(-0.1, 0.1) rad, zero velocity, root at rest."""
    noise = jax.random.uniform(rng, (self.action_size,), minval=-self.reset_noise,
                               maxval=self.reset_noise)
    return self.init_state(self._data0.qpos.at[self._qadr].set(noise), self._data0.qvel)

  def init_state(self, qpos: jax.Array, qvel: jax.Array) -> State:
    """The first state of an episode that starts at `qpos` (nq,) and `qvel` (nv,)."""
    data = self._kinematics(self._data0.replace(qpos=jnp.asarray(qpos, jnp.float32),
                                                qvel=jnp.asarray(qvel, jnp.float32)))
    feet_contact = jnp.zeros(len(self.feet))
    robot = self.robot(data, feet_contact)
    zero_terms = self.reward(robot, robot, jnp.zeros(self.action_size))
    info = {"robot": robot, "feet_contact": feet_contact, "steps": jnp.zeros((), jnp.int32),
            "truncation": jnp.zeros(())}
    return State(pipeline_state=data, obs=self.observation(robot), reward=jnp.zeros(()),
                 done=jnp.zeros(()),
                 metrics={k: jnp.zeros(jnp.shape(v), jnp.float32) for k, v in zero_terms.items()},
                 info=info)

  def step(self, state: State, action: jax.Array) -> State:
    """One control step: torques for `n_substeps` physics substeps, then observe and score.

    `done` is 1 when the episode ended; `info["truncation"]` is 1 when only the time limit ended
    it, so learners bootstrap through it. A wrapper's keys in `metrics` and `info` pass through.
    """
    action = jnp.asarray(action)
    if action.shape != (self.action_size,):
      raise ValueError(
          f"{type(self).__name__} takes an action of shape ({self.action_size},), got "
          f"{action.shape}; for a batch of envs use jax.vmap(env.step)")
    data = state.pipeline_state.replace(ctrl=action)  # MuJoCo clips ctrl to [-1, 1]
    data = self._physics(data)
    # Like PyBullet, observe joint angles and the torso speed after the last substep, but body
    # poses and contacts as the last substep's kinematics left them, one substep (4 ms) earlier.
    robot = self.robot(data, state.info["feet_contact"])
    obs = self.observation(robot)
    terms = self.reward(state.info["robot"], robot, action)
    reward = sum(terms.values())
    finite = jnp.isfinite(obs).all() & jnp.isfinite(reward) & jnp.isfinite(data.qvel).all()
    terminated = done = self.is_done(robot, terms) | ~finite
    info = dict(state.info, robot=robot, feet_contact=self._feet_contact(data))
    if BRAX_EPISODE_KEY not in state.info:  # a Python test, at trace time
      steps = state.info["steps"] + 1
      truncation = (steps >= self.episode_steps) & ~terminated
      info.update(steps=steps, truncation=truncation.astype(jnp.float32))
      done = terminated | truncation
    metrics = dict(state.metrics)
    # float32 and not weakly typed, whatever a term's code: a state's types are the same at
    # reset, after a step and after a scan, so that a program that takes one is compiled once.
    metrics.update({k: jnp.where(finite, v, 0.0).astype(jnp.float32) for k, v in terms.items()})
    return state.replace(
        pipeline_state=data,
        obs=jnp.where(finite, obs, 0.0),
        reward=jnp.where(finite, reward, 0.0),
        done=done.astype(jnp.float32),
        metrics=metrics,
        info=info)

  # ---- The task: override these for a custom one ---------------------------------------------

  def alive_bonus(self, z: jax.Array, pitch: jax.Array, robot: Robot) -> jax.Array:
    """+bonus while the robot is healthy, -1 when not (PyBullet's `alive_bonus`)."""
    raise NotImplementedError(f"{type(self).__name__} must define alive_bonus")

  def reward(self, before: Robot, after: Robot, action: jax.Array) -> dict[str, jax.Array]:
    """The named reward terms of one step; their sum is the reward."""
    alive = self.alive_bonus(after.body_xyz[2], after.body_rpy[1], after)
    electricity = (self.electricity_cost * jnp.mean(jnp.abs(action * after.joint_speeds))
                   + self.stall_torque_cost * jnp.mean(jnp.square(action)))
    at_limit = jnp.sum(jnp.abs(after.joint_pos) > 0.99)
    return {
        "alive": alive,
        "progress": self.progress(before.body_xyz, after.body_xyz),
        "electricity_cost": electricity,
        "joints_at_limit_cost": self.joints_at_limit_cost * at_limit,
        "feet_collision_cost": jnp.zeros(()),
    }

  def is_done(self, robot: Robot, terms: dict[str, jax.Array]) -> jax.Array:
    """Whether the episode terminates (not truncates) here: PyBullet's `alive < 0`."""
    return terms["alive"] < 0

  def progress(self, xyz_before: jax.Array, xyz_after: jax.Array) -> jax.Array:
    """Change of potential, -distance_to_target / dt: about the speed toward the target (m/s)."""
    # PyBullet differences two potentials of ~6e4, too large for float32; this computes the
    # change directly: |o|-|n| = (n-o).(2T-o-n) / (|o|+|n|).
    target = jnp.asarray(self.walk_target)
    old, new = xyz_before[:2], xyz_after[:2]
    d_old = jnp.linalg.norm(target - old)
    d_new = jnp.linalg.norm(target - new)
    return jnp.dot(new - old, 2 * target - old - new) / (d_old + d_new) / self.control_dt

  # ---- What the robot observes ---------------------------------------------------------------

  def robot(self, data: mjx.Data, feet_contact: jax.Array) -> Robot:
    """PyBullet's `calc_state` quantities of `data`."""
    parts = self._parts
    parts_xy = (data.xanchor[parts.after_hinge, :2].sum(0)
                + data.xanchor[parts.after_slide_anchor, :2].sum(0)
                + data.xpos[parts.after_slide_body, :2].sum(0)
                + data.xipos[parts.bodies, :2].sum(0)) / parts.count
    torso_pos = data.xipos[self._torso]
    speed = self._torso_speed(data.qpos, data.qvel)
    return Robot(
        body_xyz=jnp.concatenate([parts_xy, torso_pos[2:]]),
        body_rpy=quat_to_rpy(data.xquat[self._torso]),
        speed=speed,
        joint_pos=(data.qpos[self._qadr] - self._mid) / self._half_range,
        joint_speeds=0.1 * data.qvel[self._dofadr],
        feet_contact=feet_contact)

  def observation(self, robot: Robot) -> jax.Array:
    """PyBullet's observation, clipped to [-5, 5]: 8 + 2 * joints + feet float32 values."""
    x, y, z = robot.body_xyz
    roll, pitch, yaw = robot.body_rpy
    angle_to_target = jnp.arctan2(self.walk_target[1] - y, self.walk_target[0] - x) - yaw
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    vx = c * robot.speed[0] + s * robot.speed[1]
    vy = -s * robot.speed[0] + c * robot.speed[1]
    more = jnp.stack([z - self.initial_z, jnp.sin(angle_to_target), jnp.cos(angle_to_target),
                      0.3 * vx, 0.3 * vy, 0.3 * robot.speed[2], roll, pitch])
    joints = jnp.stack([robot.joint_pos, robot.joint_speeds], axis=-1).reshape(-1)
    obs = jnp.concatenate([more, joints, robot.feet_contact])
    return jnp.clip(obs, -5.0, 5.0).astype(jnp.float32)

  def _feet_contact(self, data: mjx.Data) -> jax.Array:
    """(F,) 1.0 where a foot's lowest point is within `contact_distance` of the floor (z = 0)."""
    feet = self._foot_geoms
    axis_z = data.geom_xmat[feet.ids, 2, 2]  # z of each capsule's long axis
    lowest = data.geom_xpos[feet.ids, 2] - jnp.abs(axis_z) * feet.half_length - feet.radius
    return jnp.any(feet.mask & (lowest <= self.contact_distance), axis=1).astype(jnp.float32)

  def _physics(self, data: mjx.Data) -> mjx.Data:
    """`data` after a control step's `n_substeps` physics steps, in MJX or MuJoCo C."""
    if self._c is None:
      return _physics(self.mjx_model, data, self.n_substeps)
    self._check_own_model()
    return self._c.step(data, self.n_substeps)

  def _kinematics(self, data: mjx.Data) -> mjx.Data:
    """Poses of every body and geom for the current qpos."""
    if self._c is None:
      return _forward_kinematics(self.mjx_model, data)
    self._check_own_model()
    return self._c.kinematics(data)

  def _check_own_model(self) -> None:
    if self.mjx_model is not self._own_model:
      raise ValueError("physics='c' steps the env's own MuJoCo model; a wrapper that swaps "
                       "env.sys (Brax's domain randomisation) needs physics='mjx'")

  # ---- What the NMA notebook inspects ------------------------------------------------------

  def action_spec(self) -> specs.BoundedArray:
    """(A,) float32 actions in [-1, 1]."""
    return specs.BoundedArray((self.action_size,), np.dtype(np.float32), "action",
                              minimum=-np.ones(self.action_size, np.float32),
                              maximum=np.ones(self.action_size, np.float32))

  def observation_spec(self) -> specs.Array:
    """(O,) float32 observations."""
    return specs.Array((self.observation_size,), np.dtype(np.float32), "observation")

  def reward_spec(self) -> specs.Array:
    """A float32 reward per step."""
    return specs.Array((), np.dtype(np.float32), "reward")

  def spec(self) -> specs.EnvironmentSpec:
    """The observation, action and reward specs together."""
    return specs.EnvironmentSpec(self.observation_spec(), self.action_spec(), self.reward_spec())

  def body_positions(self, state: State) -> dict[str, jax.Array]:
    """World position (m) of each body part's centre of mass, by name."""
    xipos = state.pipeline_state.xipos
    return {self.mj_model.body(i).name: xipos[..., i, :] for i in self._parts.bodies}

  def torso_speed(self, state: State) -> jax.Array:
    """(3,) world-frame linear velocity of the torso (m/s), PyBullet's `robot_body.speed()`."""
    return state.info["robot"].speed

  def render(self, qpos, width: int = 320, height: int = 240, camera: str = "track"):
    """RGB frames (uint8, [T,] height, width, 3) of stored qpos ([T,] nq)."""
    from mjx_hopper.envs import render
    return render.render_frames(self.mj_model, qpos, width=width, height=height, camera=camera)
