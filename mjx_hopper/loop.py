"""The host loop: compiled chunks, with logging, progress and evaluation in between.

    from mjx_hopper import loop
    result = loop.run(loop.RunConfig(env="Hopper", agent="d4pg", total_env_steps=200_000))
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import json
import os
import sys
import time
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec as P
from tqdm.auto import tqdm

from mjx_hopper import agents, checkpoint, envs, parallel, sweep, train
from mjx_hopper.logger import LEARNER_FIELDS, Logger


EVAL_ON = ("auto", "host", "train")
MAX_PENDING = 3  # evaluations started on the host beyond which training waits for the oldest


class _Pending(NamedTuple):
  """An evaluation due and not yet logged."""
  env_steps: int
  agent: Any            # a copy of the members' agents then (a chunk consumes the state's)
  diverged: np.ndarray  # the members diverged then, whose evaluation is not their best
  started: Any = None   # its result's arrays, once started (computed asynchronously)


@dataclasses.dataclass(frozen=True)
class RunConfig:
  """A whole training run: what to train, how, for how long, and where its files go.

  A sweep is a run of several members: `seeds` (default: just `seed`) times the combinations
  of `grid`'s values ({dynamic setting: values}; see `mjx_hopper.sweep`), trained at once.
  With `pbt` (a `sweep.PBT`), the members train as a population: the worst copy the best and
  perturb the grid's settings every few evaluations (docs/pbt.md).

  `env` is the task: a robot's name, a name given with `envs.register`, a `module:Class` path,
  or a `LocomotionEnv` subclass or instance (a task of your own). `env_settings` are its
  constructor's settings, and `episode_steps` its time limit (an instance's own settings count
  as given; `env_settings` wins over `episode_steps`, which wins over an instance's). Once made,
  a RunConfig holds the task's id (`envs.task_id`) in `env`, its time limit in `episode_steps`,
  and every other constructor setting, defaults included, in `env_settings`: what a checkpoint
  records of its task.
  """

  env: Any = "Hopper"
  env_settings: dict = dataclasses.field(default_factory=dict)
  agent: str = "d4pg"
  preset: str = "cpu"
  agent_overrides: dict = dataclasses.field(default_factory=dict)
  train: train.TrainConfig = train.TrainConfig()
  total_env_steps: int = 1_000_000
  max_minutes: float | None = None  # also stop (and save) after this much wall-clock time
  stop_at_return: float | None = None  # also stop once every member's evaluation reached this
  episode_steps: int | None = None  # the task's time limit; None: its default (the robots' 1000)
  eval_every: int = 200_000      # env steps between evaluations
  eval_episodes: int = 16
  # Where the evaluations run: "host", on the host's CPU, beside training; "train", on the
  # training's devices, which wait for them; "auto", "host" for a single run that trains on an
  # accelerator, else "train" (a sweep's members evaluate at once on the accelerator).
  eval_on: str = "auto"
  seed: int = 0
  seeds: tuple = ()              # a sweep's seeds (default: (seed,))
  grid: dict = dataclasses.field(default_factory=dict)  # a sweep's {setting: values}
  pbt: Any = None                # a sweep.PBT: population-based training of the members
  out_dir: str = "runs/train"     # log.csv, config.json and (by default) checkpoints/
  tensorboard_dir: str | None = None  # also log.csv's scalars as TensorBoard events here
  time_delta: float = 10.0       # seconds between terminal log lines
  checkpoint_minutes: float = 10.0
  keep_checkpoints: int = 3

  def __post_init__(self):
    task = envs.task_class(self.env)
    given = {**(envs.settings_of(self.env) if isinstance(self.env, envs.LocomotionEnv) else {}),
             **({} if self.episode_steps is None else {"episode_steps": self.episode_steps}),
             **self.env_settings}
    settings = envs.task_settings(task, given)
    object.__setattr__(self, "env", envs.task_id(task))
    object.__setattr__(self, "episode_steps", settings.pop("episode_steps"))
    object.__setattr__(self, "env_settings", settings)
    agents.config(self.agent, self.preset, **self.agent_overrides)  # raises on bad names
    for name in ("total_env_steps", "eval_every", "eval_episodes"):
      if getattr(self, name) < 1:
        raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
    if self.eval_on not in EVAL_ON:
      raise ValueError(f"eval_on must be one of {', '.join(EVAL_ON)}, got {self.eval_on!r}")
    if len(set(self.seeds)) != len(self.seeds) or not all(
        isinstance(s, int) for s in self.seeds):
      raise ValueError(f"seeds must be distinct integers, got {list(self.seeds)}")
    self.train.check()
    sweep.check_grid(self.agent, self.preset, self.grid, self.train, self.agent_overrides)
    if isinstance(self.pbt, dict):  # as a config.json holds it
      object.__setattr__(self, "pbt", sweep.PBT(**self.pbt))
    if self.pbt is not None:
      if not isinstance(self.pbt, sweep.PBT):
        raise ValueError(f"pbt takes a sweep.PBT or None, got {self.pbt!r}")
      self.pbt.check(self.grid, len(self.members()), lambda name, value: sweep.check_value(
          self.agent, self.preset, name, value, self.train, self.agent_overrides))

  def evaluates_on_host(self) -> bool:
    """Whether the evaluations run on the host's CPU, beside training (`eval_on`)."""
    if self.eval_on == "auto":
      return len(self.members()) == 1 and jax.default_backend() != "cpu"
    return self.eval_on == "host"

  def make_env(self) -> envs.LocomotionEnv:
    """The task's env, built with its settings."""
    return envs.make(self.env, episode_steps=self.episode_steps, **self.env_settings)

  def members(self) -> list[dict]:
    """Each member's seed and swept values, in member order (one member for a single run)."""
    return sweep.members(tuple(self.seeds) or (self.seed,), self.grid)

  def agent_config(self):
    """The agent's config; in a sweep of n-step values, its n_step is the largest a member
    may have (the window the replay reads), each member using its own."""
    window = {"n_step": int(self._largest("n_step"))} if "n_step" in self.grid else {}
    return agents.config(self.agent, self.preset, **{**self.agent_overrides, **window})

  def train_config(self) -> train.TrainConfig:
    """The trainer's config; in a sweep of replay ratios, the largest a member may have (the
    most updates)."""
    if "replay_ratio" not in self.grid:
      return self.train
    return dataclasses.replace(self.train, replay_ratio=self._largest("replay_ratio"))

  def _largest(self, name: str):
    """The largest value of the swept setting `name` that a member may take."""
    return (self.pbt.ranges(self.grid)[name][1] if self.pbt is not None
            else max(self.grid[name]))

  def to_json(self) -> dict:
    out = dataclasses.asdict(self)
    out["agent_config"] = dataclasses.asdict(self.agent_config())
    return out

  @classmethod
  def from_json(cls, saved: dict, env: Any = None) -> "RunConfig":
    """The RunConfig a checkpoint saved. `env`, when given, is its task, which must be the
    saved one (a class defined in a notebook or script cannot be imported by another process:
    pass it again); a task or settings other than the saved ones is a ConfigMismatch."""
    fields = {f.name for f in dataclasses.fields(cls)}
    kwargs = {k: v for k, v in saved.items() if k in fields}
    if env is not None:
      mine = envs.task_id(envs.task_class(env))
      saved_settings = {"episode_steps": saved["episode_steps"], **saved.get("env_settings", {})}
      settings = (json.loads(json.dumps(envs.settings_of(env)))
                  if isinstance(env, envs.LocomotionEnv) else saved_settings)
      if (mine, settings) != (saved["env"], saved_settings):
        given = mine + (f" {_settings_text(settings)}" if mine == saved["env"] else "")
        raise checkpoint.ConfigMismatch(
            f"the checkpoint was trained on the task {saved['env']} "
            f"{_settings_text(saved_settings)}, not {given}")
      kwargs["env"] = envs.task_class(env)
    kwargs["train"] = train.TrainConfig(**saved["train"])
    kwargs["seeds"] = tuple(saved.get("seeds", ()))
    kwargs["grid"] = {k: tuple(v) for k, v in saved.get("grid", {}).items()}
    return cls(**kwargs)


@dataclasses.dataclass
class Result:
  state: train.TrainState
  trainer: train.Trainer
  history: list[dict]            # every logged row (train and eval)
  evaluation: dict[str, Any]     # the final evaluation's per-episode arrays
  best: Any = None               # the agent at each member's best evaluation (None before any)
  best_return: Any = None        # (members,) those evaluations' mean returns

  def policy(self, which: str = "best", member: int = 0):
    """The agent state of member `member` (a single run's: 0), without the member axis: at its
    best evaluation (before any: the latest; with no finite evaluation: its agent at the
    first), or with which="latest", the latest."""
    sweep.check_which(which)
    agent = self.state.agent if which == "latest" or self.best is None else self.best
    return jax.tree.map(lambda x: x[member], agent)


def _settings_text(settings: dict) -> str:
  """A task's settings, as '(episode_steps=300, height_weight=10.0)'."""
  return "(" + ", ".join(f"{k}={v!r}" for k, v in sorted(settings.items())) + ")"


def build(cfg: RunConfig, num_members: int | None = None) -> train.Trainer:
  """The compiled trainer of `cfg`'s members (or of `num_members` of them), after checking its
  task's reward (`envs.check_task`)."""
  env = cfg.make_env()
  envs.check_task(env)
  agent = agents.make(cfg.agent, env.observation_size, env.action_size, cfg.agent_config())
  return train.make_trainer(env, agent, cfg.train_config(), eval_episodes=cfg.eval_episodes,
                            num_members=num_members or len(cfg.members()),
                            dynamic_updates="replay_ratio" in cfg.grid)


def init(cfg: RunConfig, trainer: train.Trainer, members: list[dict]) -> train.TrainState:
  """The fresh TrainState of `members` (from `cfg.members()`): each from its own seed's key,
  with its own swept values, so that a member starts as the single run of its settings."""
  keys = jnp.stack([jax.random.PRNGKey(m["seed"]) for m in members])
  return trainer.init(keys, {name: [m[name] for m in members] for name in cfg.grid})


def join_processes(coordinator: str | None = None, num_processes: int | None = None,
                   process_id: int | None = None) -> tuple[int, int]:
  """(this process's index, the number of processes) of a sweep spread over processes, from
  JAX's multi-process runtime: `jax.distributed.initialize` with these arguments (None: found
  under SLURM, Open MPI or Kubernetes) waits for every process and numbers them.

  The members of a sweep never exchange data, so each process then trains its share alone, on
  its own devices: the runtime is shut down again before JAX starts its devices, so that every
  array (and orbax's checkpoints) stays local to the process. Call it before any JAX
  computation."""
  from jax._src import distributed
  state = distributed.global_state
  jax.distributed.initialize(coordinator, num_processes, process_id)
  index, count = state.process_id, state.num_processes
  jax.distributed.shutdown()
  state.process_id, state.num_processes = 0, 1  # what JAX's devices are started with
  return index, count


def process_members(cfg: RunConfig, process: tuple[int, int] | None = None) -> list[int]:
  """The members this process trains: all of them, or for `process` = (index, count) of a
  sweep spread over processes (`join_processes`), an even, contiguous share."""
  index, count = process or (0, 1)
  total = len(cfg.members())
  if total % count:
    raise ValueError(f"{total} members do not split evenly over {count} processes")
  share = total // count
  return list(range(index * share, (index + 1) * share))


def _field_defaults(config) -> dict:
  """A config dataclass's fields' default values."""
  return {f.name: f.default for f in dataclasses.fields(config)
          if f.default is not dataclasses.MISSING}


def run(cfg: RunConfig, checkpoint_dir: str | None = None, progress: bool = True,
        print_fn=print, process: tuple[int, int] | None = None) -> Result:
  """Trains until `total_env_steps`, evaluating every `eval_every` env steps and at the end.

  Writes `out_dir`/log.csv (every chunk's and every evaluation's metrics), config.json and,
  with `cfg.tensorboard_dir`, the same scalars as TensorBoard events. Prints a short line
  every `time_delta` seconds and each evaluation, above the progress bar. Checkpoints go to
  `checkpoint_dir` (default `out_dir`/checkpoints) every `checkpoint_minutes`, at the end,
  and on Ctrl-C or SIGTERM (after the chunk in flight); a run whose checkpoint_dir already
  holds one resumes from it. A single run and a sweep take the same path: a sweep's own lines,
  ranking and curves come from `sweep.Report`.
  """
  session = _Session(cfg, checkpoint_dir, print_fn, process)
  state = session.start()
  with checkpoint.StopRequest() as stop, session.logger:
    state, evaluation = session.run_chunks(state, progress, stop)
  return session.finish(state, evaluation, stop)


class _Session:
  """One call of `run`: this process's members, their trainer, files and programs."""

  def __init__(self, cfg: RunConfig, checkpoint_dir: str | None, print_fn,
               process: tuple[int, int] | None):
    self.t_start = time.perf_counter()
    self.cfg, self.say = cfg, _above_progress_bars(print_fn)
    everyone, self.indices = cfg.members(), process_members(cfg, process)
    self.members = [everyone[i] for i in self.indices]
    self.out_dir = (os.path.join(cfg.out_dir, f"process{process[0]}")
                    if process and process[1] > 1 else cfg.out_dir)
    os.makedirs(self.out_dir, exist_ok=True)
    self.checkpoint_dir = checkpoint_dir or os.path.join(self.out_dir, "checkpoints")
    self.trainer = build(cfg, len(self.members))
    # On an accelerator, an evaluation (1,000 steps of a few envs, one after another) kept
    # Hopper's training waiting 0.6-1.9 s on an H100; the host's CPU runs it beside training,
    # its episodes spread evenly over as many of the CPU's XLA devices as they allow. `host`:
    # where its inputs go, replicated over those devices.
    self.host = None
    if cfg.evaluates_on_host():
      cpus = jax.devices("cpu")
      count = max(k for k in range(1, len(cpus) + 1) if cfg.eval_episodes % k == 0)
      self.host = NamedSharding(Mesh(np.array(cpus[:count]), ("host",)), P())
    self.mngr = checkpoint.manager(self.checkpoint_dir, cfg.keep_checkpoints)
    self.saved_config = {**cfg.to_json(), "member_indices": self.indices}
    self.report = sweep.Report(cfg.grid, self.members, self.indices, self.say,
                               single=len(everyone) == 1, pbt=cfg.pbt is not None)
    if cfg.pbt is not None and len(self.members) < 2:
      raise ValueError(f"PBT needs at least 2 members per process; this one has "
                       f"{len(self.members)}")
    self.steps_per_iteration = self.trainer.config.steps_per_iteration
    self.programs = None
    self.best = None  # the agent at each member's best evaluation
    agent_sharding = self.trainer.shardings.agent
    self._copy = jax.jit(lambda tree: jax.tree.map(jnp.copy, tree),
                         out_shardings=agent_sharding)
    self._select = jax.jit(_select_members, out_shardings=agent_sharding)
    self._copy_members = jax.jit(_copy_members, out_shardings=self.trainer.shardings,
                                 donate_argnums=0, static_argnames="data")

  def _start_compiling(self):
    """Futures of (the compiled chunk, the compiled evaluation). Compiling is the user's first
    wait, so the training chunk goes first: it is traced here, from the state's shapes (tracing
    holds Python's lock, so nothing else traces beside it), then compiles in a thread while the
    state is made (or restored). The evaluation is traced and compiled after it, beside the first
    chunks, as it is needed only at the first evaluation: the first chunk then started 5-6 s
    sooner on 2 cores and 3 s sooner on an H100 (BENCHMARKS.md, "On the 2-core CPU").
    Evaluations due before it is compiled (but a run's last one, and PBT's) do not hold up
    training: `run_chunks` keeps their agents until it is. Evaluating on the host, it is
    compiled for the host's CPU."""
    trainer = self.trainer
    shapes = jax.tree.map(
        lambda sharding, part: jax.tree.map(
            lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=sharding), part),
        trainer.shardings, jax.eval_shape(lambda: init(self.cfg, trainer, self.members)))
    keys = jax.ShapeDtypeStruct((len(self.members), 2), jnp.uint32)
    lowered = trainer.train_chunk.lower(shapes)
    pool = concurrent.futures.ThreadPoolExecutor(1)  # one after the other
    chunk = pool.submit(lowered.compile)
    if self.host is None:
      evaluator = pool.submit(lambda: trainer.evaluate.lower(shapes.agent, keys).compile())
    else:
      evaluator = pool.submit(self._compile_on_host, shapes.agent, keys)
    pool.shutdown(wait=False)
    return chunk, evaluator

  def _compile_on_host(self, agent, keys):
    """The members' evaluation compiled for the host's CPU devices, from their agents' and keys'
    shapes: `Trainer.evaluate`'s program, its episodes spread over those devices. The training
    keeps its partitioner (`parallel.gspmd_in_this_thread`)."""
    devices = list(self.host.mesh.devices.flat)
    evaluate = train.make_evaluate(self.trainer.env, self.trainer.agent, self.cfg.eval_episodes,
                                   len(self.members), devices)
    agent, keys = jax.tree.map(
        lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=self.host), (agent, keys))
    with parallel.gspmd_in_this_thread(len(devices)):
      return evaluate.lower(agent, keys).compile()

  def start(self) -> train.TrainState:
    """The state to train from (fresh, or the newest readable checkpoint's), with the programs
    compiling meanwhile (none when the newest checkpoint already ends the run), config.json
    written and the logger open."""
    cfg = self.cfg
    if (self.mngr.latest_step() or 0) * self.steps_per_iteration < cfg.total_env_steps:
      self.programs = self._start_compiling()
    state, _, self.best, record = checkpoint.resume(
        self.mngr, init(cfg, self.trainer, self.members), self.saved_config, self.say,
        defaults={"agent_config": _field_defaults(cfg.agent_config()), "env_settings": {}})
    self.report.restore(record)
    with open(os.path.join(self.out_dir, "config.json"), "w") as f:  # once resuming is agreed
      json.dump(self.saved_config, f, indent=1)
    env_steps = train.iterations(state) * self.steps_per_iteration
    if self.programs is None and env_steps < cfg.total_env_steps:  # an older step was read
      self.programs = self._start_compiling()
    self.logger = Logger(os.path.join(self.out_dir, "log.csv"), cfg.time_delta,
                         self.report.logger_print, LEARNER_FIELDS[cfg.agent],
                         cfg.tensorboard_dir, start_step=env_steps,
                         id_fields=self.report.id_fields)
    config, many = self.trainer.config, not self.report.single
    self.per_chunk = self.steps_per_iteration * config.iterations_per_chunk
    self.say(f"{cfg.env} with {cfg.agent} ({cfg.preset}): "
             f"{f'{len(self.members)} members, ' if many else ''}{cfg.train.num_envs} envs"
             f"{' each' if many else ''} on {len(jax.local_devices())} "
             f"{jax.local_devices()[0].platform} device(s), {self.per_chunk:,} env steps and "
             f"{config.updates_per_iteration * config.iterations_per_chunk:,} updates per chunk"
             f"{' per member' if many else ''}")
    return state

  def _start(self, agent, env_steps: int):
    """Starts evaluating every member's policy (`agent`, the agents at `env_steps`), on the
    host's CPU when evaluating there: its result's arrays, which JAX computes asynchronously."""
    keys = jnp.stack([jax.random.fold_in(jax.random.PRNGKey(m["seed"]), env_steps)
                      for m in self.members])
    if self.host is not None:
      agent, keys = jax.device_put((agent, keys), self.host)
    return self.programs[1].result()(agent, keys)

  def evaluate(self, pending: "_Pending", bar) -> dict:
    """Waits for a started evaluation (`pending`); its rows to the log, a sweep's line to the
    terminal, each member's best agent kept, and the members at `stop_at_return` marked."""
    _status(bar, "evaluating")
    env_steps = pending.env_steps
    result = jax.device_get(pending.started)
    returns = result["return"].mean(-1)
    self._mark_diverged(env_steps, [[] if np.isfinite(r) else ["evaluation return"]
                                    for r in returns])
    self._keep_best(pending.agent, returns, env_steps, pending.diverged)
    for m in range(len(self.members)):
      self.logger.write({"kind": "eval", **self.report.tags(m), "env_steps": env_steps,
                         "wall_s": time.perf_counter() - self.t_start,
                         "eval_return": float(np.mean(result["return"][m])),
                         "eval_return_std": float(np.std(result["return"][m])),
                         "eval_length": float(np.mean(result["length"][m]))}, force=True)
    self.report.evaluated(env_steps, returns)
    if self.cfg.stop_at_return is not None:
      newly = ~self.reached & (returns >= self.cfg.stop_at_return)
      self.reached |= newly
      if newly.any():  # training may have gone on meanwhile: the summary names these env steps
        self.reached_at = env_steps
    return result

  def evaluate_pending(self, bar, wait: bool) -> dict | None:
    """Starts every pending evaluation (`self.pending`), then logs the started ones, oldest
    first, while they are finished or more than MAX_PENDING wait (so that training cannot
    outrun a slow host); with `wait`, or evaluating on the training's devices, all of them,
    waiting for each. Returns the last one logged's result, or None."""
    self.pending = [p if p.started is not None else
                    p._replace(started=self._start(p.agent, p.env_steps)) for p in self.pending]
    result, wait = None, wait or self.host is None
    while self.pending and (wait or len(self.pending) > MAX_PENDING
                            or self._finished(self.pending[0].started)):
      result = self.evaluate(self.pending.pop(0), bar)
    return result

  @staticmethod
  def _finished(started) -> bool:
    """Whether a started evaluation's arrays are computed."""
    return all(x.is_ready() for x in jax.tree.leaves(started))

  def _keep_best(self, agent, returns, env_steps: int, diverged) -> None:
    """Keeps the agent of each member whose evaluation beat its best so far, but of those that
    had diverged (`diverged`) when the agents were taken."""
    report = self.report
    better = np.isfinite(returns) & (returns > report.best_return) & ~diverged
    if self.best is None:
      self.best = self._copy(agent)  # members with no best yet hold this one meanwhile
    elif better.any():
      self.best = self._select(better, agent, self.best)
    report.best_return = np.where(better, returns, report.best_return)
    report.best_steps = np.where(better, env_steps, report.best_steps)

  def run_chunks(self, state: train.TrainState, progress: bool, stop):
    """Chunks until the run's end, a stop request, its deadline or its target: (state, the
    last evaluation or None)."""
    cfg = self.cfg
    env_steps = train.iterations(state) * self.steps_per_iteration
    bar = (_progress_bar(cfg.total_env_steps, env_steps)
           if progress and env_steps < cfg.total_env_steps else None)
    _status(bar, "compiling the training step")
    next_eval = (env_steps // cfg.eval_every + 1) * cfg.eval_every
    evaluation, last_save = None, time.monotonic()
    self.reached = np.zeros(len(self.members), bool)  # members at stop_at_return
    self.reached_at = None  # the env steps of the evaluation where the last of them got there
    # The evaluations not yet logged: kept while the evaluation compiles (on a GPU it was ready
    # 11-19 s after the first chunk, after the first evaluation was due), and while the host
    # evaluates them beside training.
    self.pending: list[_Pending] = []
    diverged = self.report.diverged  # members whose learning went non-finite
    deadline = self.t_start + 60 * cfg.max_minutes if cfg.max_minutes else float("inf")
    while (env_steps < cfg.total_env_steps and not stop.requested
           and time.perf_counter() < deadline and not (self.reached | diverged).all()):
      t0, steps_before = time.perf_counter(), env_steps
      # A sweep's member that diverges is frozen at its agent before the chunk.
      before = None if self.report.single else self._copy(state.agent)
      state, metrics = self._chunk(state)
      env_steps = train.iterations(state) * self.steps_per_iteration
      self._check_finite(state, metrics, env_steps)
      if before is not None and diverged.any():
        state = state._replace(agent=self._select(diverged, before, state.agent))
      rate = self.per_chunk * len(self.members) / (time.perf_counter() - t0)
      updates = np.asarray(jax.device_get(state.updates))
      for m in range(len(self.members)):
        self.logger.write({"kind": "train", **self.report.tags(m), "env_steps": env_steps,
                           "updates": int(updates[m]),
                           "wall_s": time.perf_counter() - self.t_start, "steps_per_s": rate,
                           **{k: float(v[m]) for k, v in metrics.items()}})
      if diverged.all():
        break  # every member diverged: this state is not evaluated, and never saved
      self.report.trained(env_steps, rate, metrics["episode_return"], cfg.time_delta)
      last = env_steps >= cfg.total_env_steps or time.perf_counter() >= deadline
      due = env_steps >= next_eval or last
      if due:
        next_eval += cfg.eval_every
        self.pending.append(_Pending(env_steps, self._copy(state.agent), diverged.copy()))
      # A run's last evaluation and PBT's (which needs the returns) wait for the compile and
      # for the evaluations before them; the others need it compiled, and training goes on.
      wait = due and (last or cfg.pbt is not None)
      if self.pending and (wait or self.programs[1].done()):
        evaluation = self.evaluate_pending(bar, wait) or evaluation
      # PBT steps where the chunk crossed a multiple of `every` evaluations' env steps (so that
      # a resumed run steps where the straight one did), and not at the run's end.
      period = cfg.eval_every * (cfg.pbt.every if cfg.pbt is not None else 0)
      if due and period and env_steps // period > steps_before // period and (
          env_steps < cfg.total_env_steps):
        state = self._exploit_explore(state, np.asarray(evaluation["return"]).mean(-1),
                                      env_steps)
      if time.monotonic() - last_save >= 60 * cfg.checkpoint_minutes:
        if self.pending:  # a checkpoint holds every evaluation due before it
          evaluation = self.evaluate_pending(bar, wait=True) or evaluation
        self._save(state)
        last_save = time.monotonic()
      if bar is not None:
        bar.update(min(env_steps, cfg.total_env_steps) - bar.n)
        _status(bar, self.report.status(rate, self.logger))
    if self.pending:  # stopped (or diverged) while they waited: now they wait for the rest
      evaluation = self.evaluate_pending(bar, wait=True) or evaluation
    if bar is not None:
      bar.close()
    if not diverged.all():
      self._save(state)
    checkpoint.finish(self.mngr)
    return state, evaluation

  def _save(self, state: train.TrainState) -> None:
    """Starts saving the state, the best agents and the members' record."""
    checkpoint.save(self.mngr, state, {**self.saved_config, "record": self.report.record()},
                    best=self.best)

  def _chunk(self, state: train.TrainState):
    """One compiled chunk: (state, its metrics on the host)."""
    state, metrics = self.programs[0].result()(state)
    return state, jax.device_get(metrics)

  def _check_finite(self, state: train.TrainState, metrics: dict, env_steps: int) -> None:
    """Marks the members whose learner metrics (losses, values) or agent state went non-finite
    in this chunk."""
    learner = [k for k in metrics if k not in ("episode_return", "episodes", "learning")]
    finite = np.asarray(jax.device_get(_finite_members(state.agent)))
    self._mark_diverged(env_steps, [[k for k in learner if not np.isfinite(metrics[k][m])]
                                    + ([] if finite[m] else ["parameters"])
                                    for m in range(len(self.members))])

  def _mark_diverged(self, env_steps: int, bad: list[list[str]]) -> None:
    """Marks diverged each member whose `bad` (the names of what went non-finite, a list per
    member) is not empty, saying so once for each."""
    for m, names in enumerate(bad):
      if not names or self.report.diverged[m]:
        continue
      self.report.diverged[m] = True
      who = "" if self.report.single else f"member {self.indices[m]} "
      self.say(f"[diverged] {who}at {env_steps:,} env steps: {', '.join(names)} not finite"
               + ("" if self.report.single else "; frozen at its last finite agent"
                  + (" until PBT replaces it" if self.cfg.pbt else "")))

  def _exploit_explore(self, state: train.TrainState, returns, env_steps: int):
    """One PBT step: the worst members take a copy of a better member's agent (a diverged one,
    its replay and envs too), with the grid's settings perturbed (`sweep.exploit_explore`);
    says who copied whom."""
    cfg, report = self.cfg, self.report
    hparams = jax.device_get(state.agent.hparams)
    values = {name: np.asarray(jax.device_get(state.replay_ratio) if name == "replay_ratio"
                               else hparams[name]) for name in cfg.grid}
    config = self.trainer.config
    quanta = {name: 1 for name, v in values.items() if np.issubdtype(v.dtype, np.integer)}
    quanta["replay_ratio"] = config.batch_size / config.steps_per_iteration
    rng = np.random.default_rng([cfg.seed, env_steps, self.indices[0]])
    sources, new = sweep.exploit_explore(cfg.pbt, returns, report.diverged, values,
                                         cfg.pbt.ranges(cfg.grid), quanta, rng)
    moved = np.flatnonzero(sources != np.arange(len(sources)))
    ratio = new.pop("replay_ratio", np.asarray(jax.device_get(state.replay_ratio)))
    # A diverged member's replay and envs hold non-finite steps: it takes its source's too.
    lost = moved[report.diverged[moved]]
    if len(lost):
      state = self._copy_members(state, lost, sources[lost], new, ratio, data=True)
    state = self._copy_members(state, moved, sources[moved], new, ratio, data=False)
    if "replay_ratio" in cfg.grid:
      new["replay_ratio"] = ratio
    for m in moved:
      report.parents[m] = self.indices[sources[m]]
      report.diverged[m] = False
      report.values[m] = {**report.values[m], **{k: _plain(v[m]) for k, v in new.items()}}
    self.say(f"[pbt] {env_steps:,} env steps: " + "; ".join(
        f"member {self.indices[m]} copies member {report.parents[m]}, with "
        + " ".join(f"{k}={report.values[m][k]:g}" for k in cfg.grid) for m in moved))
    return state

  def finish(self, state: train.TrainState, evaluation, stop) -> Result:
    """The run's last lines (a sweep's ranking and curves first) and its Result."""
    cfg = self.cfg
    env_steps = train.iterations(state) * self.steps_per_iteration
    single, diverged = self.report.single, self.report.diverged
    if single and evaluation is not None:
      evaluation = jax.tree.map(lambda x: x[0], evaluation)  # a single run is one member
    self.report.finish(self.logger.rows, self.out_dir)
    if diverged.all():
      kept = self.mngr.latest_step()
      self.say("training diverged; nothing was saved after it: "
               + (f"the last finite checkpoint is step {kept} in {self.checkpoint_dir}, which "
                  "loop.resume continues (a lower learning rate may avoid it)" if kept is not None
                  else "no checkpoint was saved before it"))
    why = ("stopped by a signal" if stop.requested else "diverged" if diverged.all() else
           f"every member reached {cfg.stop_at_return:g}{' or diverged' if diverged.any() else ''}"
           f" by the evaluation at {self.reached_at:,} env steps"
           if (self.reached | diverged).all() else "done")
    self.say(_summary(cfg, why, env_steps, time.perf_counter() - self.t_start,
                      evaluation if single else None, self.logger.csv_path, self.checkpoint_dir))
    return Result(state, self.trainer, self.logger.rows, evaluation, self.best,
                  self.report.best_return)


def _select_members(mask, a, b):
  """Member m of pytree `a` where mask[m], else of `b`."""
  return jax.tree.map(
      lambda x, y: jnp.where(mask.reshape((-1,) + (1,) * (x.ndim - 1)), x, y), a, b)


@jax.jit
def _finite_members(tree) -> jax.Array:
  """(members,): whether every float of each member's part of `tree` is finite."""
  checks = [jnp.isfinite(x).reshape(x.shape[0], -1).all(1) for x in jax.tree.leaves(tree)
            if jnp.issubdtype(x.dtype, jnp.floating) and x.size]
  return jnp.stack(checks).all(0)


def _copy_members(state: train.TrainState, targets, sources, hparams: dict, replay_ratio,
                  data: bool):
  """`state` with the agent of each member `targets` a copy of member `sources`' (and with
  `data`, its replay, envs and episode returns too), then the dynamic settings `hparams`
  ({name: (members,) values}) and `replay_ratio` in place of every member's."""
  def copy(tree):
    return jax.tree.map(lambda x: x.at[targets].set(x[sources]), tree)
  agent = copy(state.agent)
  agent = agent._replace(hparams={**agent.hparams, **hparams})
  state = state._replace(agent=agent, replay_ratio=replay_ratio)
  if data:
    state = state._replace(replay=copy(state.replay), env=copy(state.env),
                           episode_return=copy(state.episode_return))
  return state


def _plain(value):
  """A numpy number as the Python number a config holds (float32's shortest text)."""
  return int(value) if np.issubdtype(np.asarray(value).dtype, np.integer) else float(
      str(np.float32(value)))


def _summary(cfg: RunConfig, why: str, env_steps: int, seconds: float,
             evaluation: dict | None, csv_path: str, checkpoint_dir: str) -> str:
  """The run's last line: why it ended, how far it got, its final evaluation and its files."""
  parts = [f"{why}: {env_steps:,} env steps in {seconds:.0f} s"]
  if evaluation is not None:
    parts.append(f"evaluation return {np.mean(evaluation['return']):.1f} over "
                 f"{len(evaluation['return'])} episodes")
  parts.append(f"log: {csv_path}")
  if cfg.tensorboard_dir:
    parts.append(f"TensorBoard: {cfg.tensorboard_dir}")
  parts.append(f"checkpoint: {checkpoint_dir}")
  return "; ".join(parts)


def restore(directory: str, print_fn=print, env: Any = None):
  """(RunConfig, TrainState, Trainer) of the newest readable checkpoint in `directory`: the
  whole run as saved, replay included, rebuilt from the config saved beside it. After a Colab
  restart this is the one call that gets a run back; `run(cfg, checkpoint_dir=directory)`
  continues it. `env` is the run's task, for one that cannot be imported (see
  `RunConfig.from_json`)."""
  return _restore(directory, print_fn, env)[:3]


def _restore(directory: str, print_fn, env: Any, with_best: bool = False):
  """`restore`'s (RunConfig, TrainState, Trainer), then the config item saved with that step
  and, `with_best`, the agent at the members' best evaluations (None where it holds none)."""
  mngr = _existing_manager(directory)

  def load(step):
    cfg, members, saved = _saved_run(mngr, step, env)
    trainer = build(cfg, len(members))
    state = checkpoint.restore(mngr, step, init(cfg, trainer, members))
    best = checkpoint.restore_best(mngr, step, state.agent) if with_best else None
    return cfg, state, trainer, saved, best

  step, out = checkpoint.load_newest(mngr, load, print_fn)
  print_fn(f"restored {directory}, step {step}")
  return out


def _existing_manager(directory: str):
  if not os.path.isdir(directory):
    raise FileNotFoundError(f"no checkpoint directory {directory!r}")
  mngr = checkpoint.manager(directory)
  if not mngr.all_steps():
    raise FileNotFoundError(f"no checkpoint in {directory!r}")
  return mngr


def load_policy(directory: str, member: int = 0, env: Any = None, which: str = "best",
                print_fn=print):
  """(RunConfig, agent state, Trainer) of the newest readable checkpoint in `directory`: the
  agent state of its `member`-th member (of a single run: its only one), without the member
  axis, at that member's best evaluation (or, with which="latest", the latest; a checkpoint
  saved before any evaluation holds only the latest); reads neither the replay nor the other
  agent. Says which one it loaded. `env` is the run's task, for one that cannot be imported
  (see `RunConfig.from_json`)."""
  sweep.check_which(which)
  mngr = _existing_manager(directory)

  def load(step):
    cfg, members, saved = _saved_run(mngr, step, env)
    if not 0 <= member < len(members):
      raise checkpoint.ConfigMismatch(f"member {member} is not in {directory}: it holds "
                                      f"{len(members)} member(s), 0 to {len(members) - 1}")
    trainer = build(cfg, len(members))
    like = jax.eval_shape(lambda k: init(cfg, trainer, members).agent, 0)
    best = which == "best" and checkpoint.has_best(mngr, step)
    agent_state = checkpoint.restore_agent(mngr, step, like, "best" if best else "agent")
    record = saved.get("record", {})
    score = record.get("best_return", [None] * len(members))[member] if best else None
    if score is not None:
      print_fn(f"the policy of its best evaluation: return {score:.1f} at "
               f"{record['best_env_steps'][member]:,} env steps")
    elif best:
      print_fn("the policy of its first evaluation (none of its evaluations was finite)")
    else:
      print_fn(f"the latest policy, at {step * trainer.config.steps_per_iteration:,} env steps"
               + ("" if which == "latest" else " (no evaluation was saved yet)"))
    return cfg, jax.tree.map(lambda x: x[member], agent_state), trainer

  return checkpoint.load_newest(mngr, load)[1]


def _saved_run(mngr, step, env: Any = None) -> tuple[RunConfig, list[dict], dict]:
  """The RunConfig saved at `step`, the members its checkpoint holds and the saved config item
  itself. A task that cannot be found, or is not `env`, is a ConfigMismatch: no older step
  would do better."""
  saved = checkpoint.read_config(mngr, step)
  try:
    cfg = RunConfig.from_json(saved, env)
  except ValueError as error:
    raise checkpoint.ConfigMismatch(f"{mngr.directory}: {error}") from None
  everyone = cfg.members()
  return cfg, [everyone[i] for i in saved.get("member_indices", range(len(everyone)))], saved


def extract(directory: str, member: int | str, out_dir: str, print_fn=print,
            env: Any = None) -> str:
  """Writes member `member` (an index, or "best": the member of the best evaluation) of the
  sweep checkpointed in `directory` as the checkpoint of a single run (its seed and its
  swept values now as plain settings, its latest state and its best evaluation's agent) in
  `out_dir`/checkpoints, with its config.json, so that `mjx-hopper eval` and `train`, `restore`
  and `run` take it as their own. `env` is the sweep's task, for a class that cannot be
  imported (see `resume`). Returns the checkpoint directory."""
  cfg, state, _, saved, best = _restore(directory, print_fn, env, with_best=True)
  indices = list(saved.get("member_indices", range(len(cfg.members()))))
  record = saved.get("record", {})
  if member == "best":
    scores = [-np.inf if v is None else v for v in record.get("best_return", [None])]
    if not np.isfinite(scores).any():
      raise ValueError(f"{directory}: no evaluation was saved yet, so no member is the best; "
                       "give a member's index")
    member = indices[int(np.argmax(scores))]
  try:
    target, chosen = sweep.write_member(cfg, state, best, record, indices, member, out_dir)
  except ValueError as error:
    raise ValueError(f"{directory}: {error}") from None
  print_fn(f"member {member} ({', '.join(f'{k}={v}' for k, v in chosen.items())}) of "
           f"{directory} is now the single run in {target}: its latest state, to train on"
           + (", and its best evaluation's agent, which eval loads" if best is not None else ""))
  return target


def _progress_bar(total: int, initial: int):
  return tqdm(total=total, initial=min(initial, total), unit=" env steps", unit_scale=True,
              dynamic_ncols=True)


def _status(bar, text: str) -> None:
  """Shows `text` after the progress bar's counts (nothing without a bar)."""
  if bar is not None:
    bar.set_postfix_str(text)


def _above_progress_bars(print_fn: Callable[[str], None]) -> Callable[[str], None]:
  """`print_fn`, writing above any tqdm progress bar on the terminal rather than into its
  line: tqdm clears the bar, the line is printed (and stdout flushed), tqdm redraws it."""

  def say(line: str) -> None:
    with tqdm.external_write_mode():
      print_fn(line)
      sys.stdout.flush()
  return say


def resume(directory: str, progress: bool = True, print_fn=print, env: Any = None,
           **changes) -> Result:
  """Continues the run whose checkpoints are in `directory`, from its newest readable one,
  with the config saved beside it: after a restart, the one call that goes on training.
  `changes` replace config fields that may change between a run and its resumption
  (total_env_steps, max_minutes, eval_every, ...); one the saved state depends on is refused
  with the settings that differ. `env` is the run's task, for a class that cannot be imported
  (one defined in a notebook or a script, in a new process): another task is refused."""
  mngr = _existing_manager(directory)
  cfg = checkpoint.load_newest(mngr, lambda step: _saved_run(mngr, step, env)[0], print_fn)[1]
  return run(dataclasses.replace(cfg, **changes), checkpoint_dir=directory, progress=progress,
             print_fn=print_fn)
