"""Frames and videos, rendered on the host with mujoco.Renderer (EGL or OSMesa, headless)."""

from __future__ import annotations

import os
import warnings

import mujoco
import numpy as np


def _renderer(model: mujoco.MjModel, height: int, width: int) -> mujoco.Renderer:
  try:
    return mujoco.Renderer(model, height=height, width=width)
  except mujoco.FatalError as error:
    raise RuntimeError(
        f"MuJoCo cannot render ({error}): it chose its GL backend when first imported "
        f"(MUJOCO_GL={os.environ.get('MUJOCO_GL')!r} now); on Linux without a display, call "
        "mjx_hopper.setup(), or set MUJOCO_GL=egl, before importing mjx_hopper.envs") from None


def render_frames(model: mujoco.MjModel, qpos, width: int = 320, height: int = 240,
                  camera: str = "track") -> np.ndarray:
  """uint8 RGB frames of shape ([T,] height, width, 3), one per row of `qpos` ([T,] nq)."""
  qpos = np.asarray(qpos, dtype=np.float64)
  if qpos.shape[-1] != model.nq or qpos.ndim not in (1, 2):
    raise ValueError(f"qpos must have shape (nq,) or (T, nq) with nq={model.nq}, "
                     f"got {qpos.shape}")
  data = mujoco.MjData(model)
  frames = []
  with _renderer(model, height, width) as renderer:
    for q in np.atleast_2d(qpos):
      data.qpos[:] = q
      mujoco.mj_kinematics(model, data)
      mujoco.mj_comPos(model, data)  # the tracking camera follows the centre of mass
      mujoco.mj_camlight(model, data)
      renderer.update_scene(data, camera=camera)
      frames.append(renderer.render())
  frames = np.stack(frames)
  return frames if qpos.ndim == 2 else frames[0]


def write_mp4(path: str, frames: np.ndarray, fps: float) -> str:
  """Writes uint8 frames (T, H, W, 3) to an H.264 mp4 at `path`; returns the path."""
  import imageio_ffmpeg

  frames = np.asarray(frames)
  if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8:
    raise ValueError(f"frames must be uint8 of shape (T, H, W, 3), got {frames.dtype} "
                     f"{frames.shape}")
  height, width = frames.shape[1:3]
  os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
  writer = imageio_ffmpeg.write_frames(path, (width, height), fps=fps, macro_block_size=1,
                                       codec="libx264", pix_fmt_out="yuv420p",
                                       output_params=["-loglevel", "error"])
  with warnings.catch_warnings():
    # JAX warns on any fork; this one only execs the ffmpeg binary.
    warnings.filterwarnings("ignore", message="os.fork", category=RuntimeWarning)
    writer.send(None)
  for frame in frames:
    writer.send(np.ascontiguousarray(frame))
  writer.close()
  return path
