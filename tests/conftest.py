"""Test set-up: two XLA CPU devices (so batches are sharded), a persistent compile cache, and
one trainer per config for each test worker."""

import functools
import os
from importlib.metadata import version

# Two devices, so that batches are sharded. The suite's time is mostly compiling, so: XLA:CPU's
# loop emitters instead of its fusion emitters, which compile MJX's physics faster (users keep
# XLA's default, whose programs' speed depends on the robot; jaxlib 0.11 dropped the loop
# emitters and refuses their flag), and LLVM's optimisation level 0, which compiles fastest;
# the programs that run whole 1,000-step episodes take level 1 (LONG_RUNNING), as level 0 runs
# them several times slower (benchmarks/results/compile_flags_cpu.json). And
# single-threaded matrix products within a device: XLA:CPU splits a product over its thread
# pool only in single-device programs, which changes the order of its sums, so a sweep member
# would not be bit-identical to its single run on one device (test_sweep.py). The measurements
# behind each choice are in the commits that made it. A flag in $XLA_FLAGS wins over these.
LOOP_EMITTERS = ("--xla_cpu_use_fusion_emitters=false"
                 if tuple(map(int, version("jaxlib").split(".")[:2])) < (0, 11) else "")
TEST_XLA_FLAGS = (f"--xla_force_host_platform_device_count=2 {LOOP_EMITTERS} "
                  "--xla_cpu_multi_thread_eigen=false --xla_backend_optimization_level=0")
# Once: xdist's workers inherit the controller's flags, and JAX's cache key holds every flag,
# repeats too, so a repeat would set the workers' programs apart from those of other processes.
if not os.environ.get("XLA_FLAGS", "").startswith(TEST_XLA_FLAGS):
  os.environ["XLA_FLAGS"] = TEST_XLA_FLAGS + " " + os.environ.get("XLA_FLAGS", "")
# The compile options of a program that runs long: `jax.jit(f, compiler_options=LONG_RUNNING)`.
LONG_RUNNING = {"xla_backend_optimization_level": 1}

# One compile cache for the tests and the processes they start (CLI runs, notebooks), so that
# a program compiled by one is loaded by the others.
os.environ.setdefault("MJX_HOPPER_JAX_CACHE", os.path.join(
    os.path.dirname(os.path.abspath(__file__)), "..", ".cache", "jax"))

import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import mjx_hopper  # noqa: E402

pytest_plugins = ["crashes", "ledger"]

import crashes  # noqa: E402

mjx_hopper.setup()  # before MuJoCo is imported, which reads MUJOCO_GL once

from mjx_hopper.run import trainers  # noqa: E402


@pytest.fixture(scope="session", autouse=True)
def shared_builds():
  """`trainers.build`, through which every path builds its trainer (`loop.run` and
  `loop.resume`, `checkpoints.restore`, `.load_policy` and `.extract`,
  `export.export_checkpoint` and the in-process CLI), memoised on the plan's `key` for a
  test worker's whole session: each config's trainer is traced once, across the test files
  that the worker runs (tracing one takes about 15 s of CPU, even when its programs come from
  the compile cache). A trainer is pure functions, so a run is the same with a trainer built
  once or again. JAX's caches are kept (`trainers.assemble`), not emptied for each new trainer
  as `trainers.build` empties them: the memoised trainers and envs would be traced again, which
  made the quick tier trace far longer.
  `trainers.build.__wrapped__` is the product's."""
  built = {}

  @functools.wraps(trainers.build)
  def cached(plan):
    if plan.key not in built:
      built[plan.key] = trainers.assemble(plan)
    return built[plan.key]
  with pytest.MonkeyPatch.context() as patch:
    patch.setattr(trainers, "build", cached)
    yield


# The test files, or groups of them (GROUPS), that take longest from an empty compile cache
# (`pytest --durations=0`), longest first: the two test workers take them in this order, so
# that neither is left with a long one at the end while the other idles (scripts/test.sh turns
# off xdist's own order, by number of tests). A file not listed goes after them.
LONGEST_FIRST = ("the notebook's programs", "hopper programs", "tiny trainers", "test_sweep.py",
                 "test_episodes.py", "test_pretrained.py", "test_dpg.py",
                 "test_mpo.py", "test_new_agent.py", "test_crashes.py", "test_checkpoint.py")
# Files that build the same programs, run in one worker in this order (tests/crashes.py's
# scheduler takes each group as one unit of work; any other file is a unit of its own): a
# trainer or env program is then traced once (`shared_builds`, `make_env`) and compiled once,
# never by both workers at once, and the files that train in processes of their own find its
# programs in the cache.
GROUPS = {"tiny trainers": ("test_train.py", "test_run_folder.py", "test_runlock.py",
                            "test_presets.py", "test_logger.py", "test_notebook_helpers.py",
                            "test_export.py", "test_terminal.py", "test_start.py",
                            "test_compile_cache.py", "test_packaging.py", "test_kept.py"),
          # The notebook's Ant event, Walker2D and high jump, trained by test_tasks.py first.
          "the notebook's programs": ("test_tasks.py", "test_notebooks.py"),
          "hopper programs": ("test_env_api.py", "test_episode_starts.py", "test_gymnasium.py",
                              "test_brax.py", "test_observation.py")}
_GROUP_OF = {name: group for group, names in GROUPS.items() for name in names}


def pytest_configure(config):
  config.stash[crashes.UNIT_OF_FILE] = lambda path: _GROUP_OF.get(os.path.basename(path), path)


def pytest_collection_modifyitems(items):
  rank = {name: i for i, name in enumerate(LONGEST_FIRST)}

  def order(item):
    name = item.path.name
    group = _GROUP_OF.get(name, name)
    return rank.get(group, len(rank)), GROUPS.get(group, (name,)).index(name)
  items.sort(key=order)  # stable: tests keep their order


ROBOTS = ("Hopper", "Walker2D", "HalfCheetah", "Ant", "Humanoid")
ORACLE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "oracle")
_ENVS, _ORACLE = {}, {}


def make_env(env_id, physics="mjx"):
  """One env per id and physics engine for the whole session, so compiled functions are
  shared."""
  from mjx_hopper import envs
  if (env_id, physics) not in _ENVS:
    _ENVS[env_id, physics] = envs.make(env_id, **({} if physics == "mjx" else
                                                  {"physics": physics}))
  return _ENVS[env_id, physics]


def oracle(name):
  """What PyBullet computed for robot `name` (or "euler"), as tests/record_oracle.py recorded
  it in tests/oracle/NAME.npz: a dict of arrays, without the `meta` record."""
  if name not in _ORACLE:
    with np.load(os.path.join(ORACLE, f"{name}.npz")) as data:
      _ORACLE[name] = {k: data[k] for k in data.files if k != "meta"}
  return _ORACLE[name]


@pytest.fixture(scope="session")
def hopper():
  return make_env("Hopper")


@pytest.fixture(scope="session")
def hopper_reset(hopper_resets):
  """`hopper.reset` of one key, through `hopper_resets`' program."""
  return lambda key: jax.device_put(jax.tree.map(lambda x: x[0],
                                                 hopper_resets(np.asarray(key)[None])))


@pytest.fixture(scope="session")
def hopper_step(hopper):
  return jax.jit(hopper.step)


@pytest.fixture(scope="session")
def hopper_resets(hopper):
  """`hopper.reset` of each of `keys` (any number), through one program of 64 resets: host
  arrays."""
  program, batch = jax.jit(jax.vmap(hopper.reset)), 64

  def reset(keys):
    keys = np.asarray(keys)
    padded = np.concatenate([keys, np.zeros((-len(keys) % batch, *keys.shape[1:]), keys.dtype)])
    batches = [jax.device_get(program(b)) for b in padded.reshape(-1, batch, *keys.shape[1:])]
    return jax.tree.map(lambda *x: np.concatenate(x)[:len(keys)], *batches)
  return reset


_EPISODES = {}


def mjx_episodes(env_id, num_episodes=128, physics="mjx"):
  """Random- and zero-action episode statistics of `env_id` stepped by `physics`, with the qpos
  of episode 0, from one compiled program per robot and engine (`scale` 1 is random actions, 0
  zero actions)."""
  from mjx_hopper.core import rollout
  if (env_id, physics) not in _EPISODES:
    env = make_env(env_id, physics)

    @functools.partial(jax.jit, compiler_options=LONG_RUNNING)
    def run(key, scale):
      random = rollout.random_policy(env.action_size)
      return rollout.episodes(env, lambda obs, k: scale * random(obs, k), key, num_episodes,
                              record_qpos=True)

    _EPISODES[env_id, physics] = {policy: jax.device_get(run(jax.random.PRNGKey(1), scale))
                                  for policy, scale in (("random", 1.0), ("zero", 0.0))}
  return _EPISODES[env_id, physics]
