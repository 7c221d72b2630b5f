"""A robot's MuJoCo model, built and checked as its env class declares it, and the fixed indices
that its env reads from it: its root joints, PyBullet's parts and its feet."""

from __future__ import annotations

import os
from typing import NamedTuple

import mujoco
import numpy as np

ASSETS = os.path.join(os.path.dirname(__file__), "assets")


def load(env) -> mujoco.MjModel:
  """`env`'s MJCF file with `env.edit_model` applied, its gears set from its power and the
  contacts of bodies off `env.floor_bodies` turned off; a ValueError where the file and the
  class disagree (timestep, actuated joints, body names)."""
  model = mujoco.MjModel.from_xml_path(os.path.join(ASSETS, env.xml_file))
  env.edit_model(model)
  if abs(model.opt.timestep * env.n_substeps - env.control_dt) > 1e-9:
    raise ValueError(f"{env.xml_file}: timestep {model.opt.timestep} x {env.n_substeps} "
                     f"substeps is not the control dt {env.control_dt}")
  act_joints = tuple(model.joint(model.actuator_trnid[i, 0]).name for i in range(model.nu))
  if act_joints != env.joints:
    raise ValueError(f"{env.xml_file}: actuators drive {act_joints}, expected {env.joints}")
  model.actuator_gear[:, 0] = env.power * np.asarray(env.power_coefs)
  if env.floor_bodies is not None:
    bodies = [model.body(b).name for b in range(1, model.nbody)]
    unknown = sorted(set(env.floor_bodies) - set(bodies))
    if unknown:
      raise ValueError(f"{type(env).__name__}.floor_bodies names {unknown}, which "
                       f"{env.xml_file} lacks; its bodies are {bodies}")
    touching = [model.body(b).id for b in env.floor_bodies]
    off = (model.geom_bodyid != 0) & ~np.isin(model.geom_bodyid, touching)
    model.geom_contype[off] = model.geom_conaffinity[off] = 0
  return model


def root_kind(model: mujoco.MjModel, torso: int, xml_file: str) -> str:
  """'planar' (slide x, slide z, hinge y at the torso's origin) or 'free'."""
  joints = np.flatnonzero(model.jnt_bodyid == torso)
  types = [int(model.jnt_type[j]) for j in joints]
  planar = [int(mujoco.mjtJoint.mjJNT_SLIDE)] * 2 + [int(mujoco.mjtJoint.mjJNT_HINGE)]
  axes = model.jnt_axis[joints]
  if types == [int(mujoco.mjtJoint.mjJNT_FREE)]:
    return "free"
  if (types == planar and np.allclose(axes, np.eye(3)[[0, 2, 1]])
      and np.allclose(model.jnt_pos[joints], 0) and list(joints) == [0, 1, 2]):
    return "planar"
  raise ValueError(f"{xml_file}: the torso's root joints must be one free joint, or slide x, "
                   "slide z and hinge y at its origin")


class BulletParts(NamedTuple):
  """Where PyBullet's "parts" are, whose x, y it averages: the floor (fixed at the origin), a
  link per body (`bodies`), and a massless link placed after each joint but a free one. After a
  hinge that link sits at the hinge's anchor (`after_hinge`: joints); after a slide, where the
  slide took it: at the next joint's anchor of the same body (`after_slide_anchor`: joints), or
  at the body's frame after its last joint (`after_slide_body`: bodies). `count`: all of them."""
  bodies: np.ndarray
  after_hinge: np.ndarray
  after_slide_anchor: np.ndarray
  after_slide_body: np.ndarray
  count: int


def bullet_parts(model: mujoco.MjModel) -> BulletParts:
  """`model`'s `BulletParts`."""
  hinge, free = int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_FREE)
  last = np.append(model.jnt_bodyid[1:] != model.jnt_bodyid[:-1], True)
  kinds = np.asarray(model.jnt_type)
  bodies = np.arange(1, model.nbody)
  return BulletParts(bodies, np.flatnonzero(kinds == hinge),
                     np.flatnonzero((kinds != hinge) & (kinds != free) & ~last) + 1,
                     model.jnt_bodyid[(kinds != hinge) & (kinds != free) & last],
                     int(np.sum(kinds != free)) + len(bodies) + 1)


class FootGeoms(NamedTuple):
  """The feet's capsule and sphere geoms: ids, half-lengths, radii (G,), owner mask (F, G)."""
  ids: np.ndarray
  half_length: np.ndarray
  radius: np.ndarray
  mask: np.ndarray


def foot_geoms(model: mujoco.MjModel, feet: tuple[str, ...], xml_file: str) -> FootGeoms:
  """`model`'s `FootGeoms` of the bodies `feet`; a ValueError for a foot geom of another
  shape."""
  capsule, sphere = int(mujoco.mjtGeom.mjGEOM_CAPSULE), int(mujoco.mjtGeom.mjGEOM_SPHERE)
  ids, owner = [], []
  for f, foot in enumerate(feet):
    geoms = np.flatnonzero(model.geom_bodyid == model.body(foot).id)
    for g in geoms:
      if model.geom_type[g] not in (capsule, sphere):
        raise ValueError(f"{xml_file}: foot geom {model.geom(g).name!r} must be a capsule or a "
                         "sphere")
    ids += list(geoms)
    owner += [f] * len(geoms)
  ids = np.array(ids)
  is_capsule = model.geom_type[ids] == capsule
  half_length = np.where(is_capsule, model.geom_size[ids, 1], 0.0)
  mask = np.arange(len(feet))[:, None] == np.array(owner)[None, :]
  return FootGeoms(ids, half_length, model.geom_size[ids, 0], mask)
