"""A trained policy as one .npz file that runs with NumPy alone.

    from mjx_hopper.faces import export
    export.export_checkpoint("runs/train/checkpoints", "policy.npz")   # needs JAX
    policy = export.load("policy.npz")                                # NumPy only
    action = policy(obs)                  # (O,) -> (A,), or a batch (N, O) -> (N, A)

The file holds the deterministic policy's layers (arrays "w{i}", "b{i}" and, after a layer with
LayerNorm, "ln{i}_scale" and "ln{i}_bias") and a JSON entry "meta": the layers' structure, the
task's id and settings, the sizes, the versions, the file's format and the evaluation the policy
scored. `forward` is the whole network; docs/export.md has it in a dozen lines of NumPy.

This module imports JAX only inside the functions that need it (`export_checkpoint`,
`evaluate_file`), so that `load` runs where JAX is not installed.
"""

from __future__ import annotations

import json
import os
import zipfile
import zlib
from typing import Any, Callable

import numpy as np

import mjx_hopper

# The file's layout. Every change to it raises FORMAT; `load` refuses a newer one.
FORMAT = 1
LAYER_NORM_EPSILON = 1e-6  # flax's LayerNorm default, which the agents' networks use


def round_bfloat16(x: np.ndarray) -> np.ndarray:
  """float32 values rounded to the nearest bfloat16 (ties to even), kept as float32: what a
  cast to bfloat16 and back gives."""
  bits = np.asarray(x, np.float32).view(np.uint32)
  rounded = (bits + np.uint32(0x7FFF) + ((bits >> 16) & 1)) & np.uint32(0xFFFF0000)
  return np.where(np.isnan(x), x, rounded.view(np.float32)).astype(np.float32)


def forward(arrays, meta: dict, obs, xp=np, rounding: Callable | None = None):
  """The policy's actions (..., A) for observations (..., O), in float32.

  Each layer is a Dense, then LayerNorm (statistics in float32) and its activation; then tanh,
  or a clip to [-1, 1]. A bfloat16 layer computes as XLA compiles flax's bfloat16 layers: its
  inputs, weights, product and results are rounded to bfloat16, but for a result that the
  program only widens back to float32 (the sum before LayerNorm, whose statistics are float32,
  and an activation before a float32 layer), which XLA keeps in float32. `xp` is the array
  module (NumPy, or jax.numpy with `rounding` its own bfloat16 cast)."""
  low = rounding or round_bfloat16
  layers = meta["layers"]
  x = xp.asarray(obs, xp.float32)
  for i, layer in enumerate(layers):
    r = low if layer["dtype"] == "bfloat16" else (lambda v: v)
    x = r(r(x) @ r(arrays[f"w{i}"])) + r(arrays[f"b{i}"])
    if layer["norm"]:
      mean = x.mean(-1, keepdims=True)
      var = xp.maximum((x * x).mean(-1, keepdims=True) - mean * mean, 0.0)
      x = ((x - mean) / xp.sqrt(var + LAYER_NORM_EPSILON) * arrays[f"ln{i}_scale"]
           + arrays[f"ln{i}_bias"])
    x = r(x)
    if layer["activation"] == "tanh":
      x = xp.tanh(x)
    elif layer["activation"] == "elu":
      x = xp.where(x > 0, x, r(xp.expm1(xp.minimum(x, 0.0))))
    if i + 1 < len(layers) and layers[i + 1]["dtype"] == "bfloat16":
      x = r(x)
  return xp.tanh(x) if meta["output"] == "tanh" else xp.clip(x, -1.0, 1.0)


class Policy:
  """An exported policy: call it on observations (O,) or (N, O) for actions (A,) or (N, A) in
  [-1, 1], as float32 NumPy arrays. `meta` is what the file records."""

  def __init__(self, arrays: dict[str, np.ndarray], meta: dict, path: str = "policy"):
    self.arrays, self.meta, self.path = arrays, meta, path
    self.observation_size = meta["observation_size"]
    self.action_size = meta["action_size"]

  def __call__(self, obs) -> np.ndarray:
    obs = np.asarray(obs, np.float32)
    if obs.ndim not in (1, 2) or obs.shape[-1] != self.observation_size:
      raise ValueError(f"{self.path} takes observations of shape ({self.observation_size},) or "
                       f"(N, {self.observation_size}), got {obs.shape}")
    return forward(self.arrays, self.meta, obs)

  def __repr__(self) -> str:
    m = self.meta
    task = m.get("task", {}).get("env", "its task")
    return (f"Policy({m['agent']} on {task}: {self.observation_size} observations -> "
            f"{self.action_size} actions, {m['compute_dtype']})")


def load(path: str) -> Policy:
  """The policy in an exported file (see `export_checkpoint`), as a NumPy function. The file is
  read without unpickling anything; one that is not an export, is damaged, or is of a newer
  format is a one-line ValueError naming it."""
  arrays = _arrays(path)
  if "meta" not in arrays:
    raise ValueError(f"{path} is not a policy exported by mjx_hopper: it holds the arrays "
                     f"{sorted(arrays)[:8]} and no 'meta' entry")
  try:
    meta = json.loads(str(arrays.pop("meta")))
  except ValueError:
    meta = None
  if not isinstance(meta, dict):
    raise ValueError(f"{path} is not a policy exported by mjx_hopper: its 'meta' entry is not "
                     "the JSON that export writes")
  found = meta.get("format", 0)
  if isinstance(found, int) and found > FORMAT:
    by = meta.get("versions", {}).get("mjx_hopper", "another version")
    raise ValueError(f"{path} has policy format {found} (written by mjx_hopper {by}), and "
                     f"mjx_hopper {mjx_hopper.__version__} reads format {FORMAT}: load it with "
                     f"mjx_hopper {by} or newer")
  problem = (_check_layers(arrays, meta) if isinstance(found, int) and 1 <= found
             else f"its format is {found!r}")
  if problem:
    raise ValueError(f"{path} is not a policy exported by mjx_hopper (format {FORMAT}): "
                     f"{problem}")
  return Policy(arrays, meta, path)


def _arrays(path: str) -> dict[str, np.ndarray]:
  """The arrays of the .npz file at `path`, read with allow_pickle=False; a one-line ValueError
  for any other file (FileNotFoundError where there is none)."""
  unreadable = (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error)
  expected = f"{path} is not a policy file written by `mjx-hopper export` (an .npz)"
  try:
    f = np.load(path, allow_pickle=False)
  except FileNotFoundError:
    raise FileNotFoundError(f"no policy file {path!r}") from None
  except unreadable as error:
    raise ValueError(f"{expected}: NumPy cannot read it ({type(error).__name__})") from None
  if not isinstance(f, np.lib.npyio.NpzFile):
    raise ValueError(f"{expected}: it holds one array")
  try:
    with f:
      return {k: f[k] for k in f.files}
  except unreadable as error:  # a damaged archive, or arrays of Python objects
    raise ValueError(f"{expected}: its arrays cannot be read ({type(error).__name__})"
                     ) from None


def _check_layers(arrays: dict, meta: dict) -> str | None:
  """What in `meta` or `arrays` an export of this format would not hold, or None."""
  keys = ("agent", "compute_dtype", "observation_size", "action_size", "layers", "output")
  missing = [k for k in keys if k not in meta]
  if missing:
    return f"its meta lacks {missing}"
  size = meta["observation_size"]
  try:
    for i, layer in enumerate(meta["layers"]):
      if not {"norm", "dtype", "activation"} <= set(layer):
        return f"layer {i} lacks some of 'norm', 'dtype' and 'activation'"
      names = [f"w{i}", f"b{i}"] + ([f"ln{i}_scale", f"ln{i}_bias"] if layer["norm"] else [])
      if any(name not in arrays for name in names):
        return f"layer {i} lacks some of the arrays {names}"
      w = arrays[f"w{i}"]
      if w.ndim != 2 or w.shape[0] != size or arrays[f"b{i}"].shape != (w.shape[1],):
        return f"layer {i}'s weights {w.shape} do not take {size} inputs"
      size = w.shape[1]
  except (KeyError, TypeError):
    return "its meta's layers are not laid out as export writes them"
  if size != meta["action_size"]:
    return f"its last layer gives {size} actions, and its meta says {meta['action_size']}"
  return None


# ---- Writing: from an agent's parameters, or from a checkpoint (JAX) --------------------------

def policy_of(agent: str, agent_config, policy_params, observation_size: int,
              action_size: int, **meta) -> Policy:
  """The NumPy policy of agent `agent`'s policy params (its state's `policy`), as the agent's
  registered `exported_policy` lays it out, with `meta`'s other entries (task, evaluation, ...)
  recorded as given."""
  from mjx_hopper import agents

  exported_policy = agents.spec(agent).exported_policy
  if exported_policy is None:
    raise ValueError(f"cannot export agent {agent!r}: it was registered without an "
                     "exported_policy (see agents.register)")
  layers, output = exported_policy(policy_params, agent_config)
  arrays = {}
  for i, (named, _) in enumerate(layers):  # w0, b0, ln0_scale, ln0_bias, w1, ...
    arrays.update({(f"ln{i}_{k[3:]}" if k.startswith("ln_") else f"{k}{i}"): v
                   for k, v in named.items()})
  meta = {"format": FORMAT, "agent": agent, "compute_dtype": agent_config.compute_dtype,
          "observation_size": observation_size, "action_size": action_size,
          "layers": [layer for _, layer in layers], "output": output, **meta}
  return Policy(arrays, meta)


def save(policy: Policy, out: str) -> str:
  """Writes `policy` to `out` (its folder made if missing), whole or not at all; returns it."""
  os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
  meta = np.array(json.dumps(policy.meta, default=str))
  with open(out + ".tmp", "wb") as f:
    np.savez(f, meta=meta, **policy.arrays)
  os.replace(out + ".tmp", out)
  return out


def export_checkpoint(directory: str, out: str, member: int | str | None = None,
                      which: str = "best", env: Any = None, print_fn=print) -> str:
  """Writes the policy of a checkpoint in `directory` to the file `out` and returns its path:
  the agent of the best evaluation, or with which="latest", the latest. `member` is a member's
  index, or "best" (the member of the best evaluation); required for a sweep, optional for a
  single run. `env` is the run's task, for a class that cannot be imported (see
  `loop.resume`). Errors are one-line ValueErrors or FileNotFoundErrors, and nothing is
  written."""
  from mjx_hopper.run import checkpoints

  plan, state, trainer, saved, position, best = checkpoints.load_member(directory, member, env,
                                                                        which, print_fn)
  cfg = plan.cfg
  evaluation = _evaluation(saved.record, position, best, cfg.eval_episodes,
                           saved.step * trainer.config.steps_per_iteration)
  policy = policy_of(cfg.agent, plan.agent_config, state.policy,
                     trainer.env.observation_size, trainer.env.action_size,
                     task=_task(cfg.task_id, plan.task_settings),
                     member=saved.indices[position],
                     evaluation=evaluation,
                     checkpoint_format=saved.item.get("checkpoint_format", 1),
                     versions={"mjx_hopper": mjx_hopper.__version__, "numpy": np.__version__},
                     trained_with=saved.item.get("versions", {}), run_config=cfg.to_json())
  save(policy, out)
  score = "" if evaluation["return"] is None else f", return {evaluation['return']:.1f}"
  print_fn(f"exported the {evaluation['which']} policy of {directory}{score} "
           f"({cfg.agent} on {cfg.task_id}) to {out}")
  return out


def _task(task_id: str, task_settings: dict) -> dict:
  """The task a run trains, by id, with every setting resolved (`Plan.task_settings`)."""
  settings = dict(task_settings)
  return {"env": task_id, "episode_steps": settings.pop("episode_steps"),
          "env_settings": settings}


def _evaluation(record: dict, position: int, best: bool, episodes: int, env_steps: int) -> dict:
  """What the file records of the policy's evaluation: the best one's mean return and env
  steps, or for the latest policy, its env steps (it was not evaluated when saved)."""
  if not best:
    return {"which": "latest", "return": None, "env_steps": env_steps, "episodes": episodes}
  score = record.get("best_return", [None] * (position + 1))[position]
  at = record.get("best_env_steps", [None] * (position + 1))[position]
  return {"which": "best", "return": score, "env_steps": at, "episodes": episodes}


# ---- Evaluating a file (JAX) ------------------------------------------------------------------

def make_env(policy: Policy, env: Any = None):
  """The task the policy was trained on, rebuilt from its recorded id and settings; `env` (a
  class, a `module:Class` path or a name) stands in for a task that cannot be imported."""
  from mjx_hopper import envs

  task = policy.meta["task"]
  if env is None and task["env"].startswith("__main__:"):
    raise ValueError(f"{policy.path} was trained on {task['env']}, a task defined in a notebook "
                     "or a script, which cannot be imported: pass its class as --env "
                     "module:Class (env= in Python)")
  made = envs.make(env if env is not None else task["env"], episode_steps=task["episode_steps"],
                   **task["env_settings"])
  if (made.observation_size, made.action_size) != (policy.observation_size, policy.action_size):
    raise ValueError(f"{policy.path} acts on {policy.observation_size} observations and "
                     f"{policy.action_size} actions; the task {envs.task_id(type(made))} has "
                     f"{made.observation_size} and {made.action_size}")
  return made


def evaluate_file(path: str, episodes: int = 16, seed: int = 0, video_path: str | None = None,
                  env: Any = None, print_fn=print, frame_every: int = 1) -> dict[str, np.ndarray]:
  """Evaluates the exported policy in `path` on its task (see `make_env`) over `episodes`
  episodes, compiled, and with `video_path`, films episode 0 as an mp4 of every `frame_every`th
  step, in real time (rendering on a CPU takes longer than the episode). Returns the
  per-episode "return" and "length" (and the reward terms' means)."""
  import jax
  import jax.numpy as jnp

  from mjx_hopper.core import rollout
  from mjx_hopper.envs import render

  if frame_every < 1:
    raise ValueError(f"frame_every must be >= 1, got {frame_every}")
  policy = load(path)
  task = make_env(policy, env)
  arrays = {k: jnp.asarray(v) for k, v in policy.arrays.items()}

  def run(arrays, key):
    def act(obs, key):
      # reduce_precision, not a cast to bfloat16 and back, which XLA may drop (excess precision)
      return forward(arrays, policy.meta, obs, jnp,
                     lambda x: jax.lax.reduce_precision(x, exponent_bits=8, mantissa_bits=7))
    return rollout.episodes(task, act, key, episodes, record_qpos=video_path is not None)

  # The weights are arguments, not constants folded into the program.
  result = jax.device_get(jax.jit(run)(arrays, jax.random.PRNGKey(seed)))
  returns = np.asarray(result["return"])
  print_fn(f"{policy.meta['task']['env']} / {policy.meta['agent']} ({path}): return "
           f"{returns.mean():.1f} +- {returns.std():.1f}, length "
           f"{np.mean(result['length']):.0f} over {episodes} episodes")
  if video_path is not None:
    length = int(result["length"][0])
    qpos = np.asarray(result.pop("qpos")[:length + 1:frame_every])
    render.write_mp4(video_path, render.render_frames(task.mj_model, qpos),
                     fps=1 / (task.dt * frame_every))
    print_fn(f"video of episode 0 ({length} steps, return {returns[0]:.1f}): {video_path}")
  return result


# ---- Shipped policies: one per robot, trained by benchmarks/pretrain.py -----------------------

PRETRAINED = os.path.join(os.path.dirname(os.path.abspath(__file__)), "pretrained")


def pretrained_path(robot: str) -> str:
  """The path of robot `robot`'s shipped policy file; a one-line ValueError for another name."""
  shipped = sorted(f[:-4] for f in os.listdir(PRETRAINED) if f.endswith(".npz")) \
      if os.path.isdir(PRETRAINED) else []
  if robot not in shipped:
    raise ValueError(f"no pretrained policy for {robot!r}; the shipped ones are {shipped}")
  return os.path.join(PRETRAINED, f"{robot}.npz")


def pretrained(robot: str) -> Policy:
  """The policy shipped with the package for `robot` (Hopper, Walker2D, HalfCheetah, Ant,
  Humanoid), trained by this project's own gpu preset; NumPy alone runs it."""
  return load(pretrained_path(robot))


def fingerprint(env) -> dict:
  """What a policy depends on of its task `env`: its model file's hash and its observation
  and action sizes. A shipped file records it; a change means the file needs retraining."""
  import hashlib

  from mjx_hopper.envs.model import ASSETS
  with open(os.path.join(ASSETS, env.xml_file), "rb") as f:
    model = hashlib.sha256(f.read()).hexdigest()[:16]
  return {"model_sha256": model, "observation_size": env.observation_size,
          "action_size": env.action_size}
