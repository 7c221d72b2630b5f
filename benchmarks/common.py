"""What several benchmarks share: the command line, a compiled call timed again and again, a
worker process with its own device count, the evaluations of a run's log.csv, the results file
and markdown tables."""

from __future__ import annotations

import argparse
import csv
import json
import os
import shlex
import shutil
import subprocess
import sys
import time

EVAL_FIELDS = ("wall_s", "env_steps", "eval_return", "eval_return_std", "eval_length")


def pybullet_oracle():
  """tests/pybullet_oracle.py, PyBullet's own envs (they need the oracle extra)."""
  tests = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests")
  if tests not in sys.path:
    sys.path.insert(0, tests)
  import pybullet_oracle
  return pybullet_oracle


def parser(doc: str) -> argparse.ArgumentParser:
  """An argument parser whose help is the script's docstring `doc`, as written."""
  return argparse.ArgumentParser(description=doc,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)


def parse(p: argparse.ArgumentParser, work=None) -> argparse.Namespace:
  """`p`'s arguments. With `work`, a hidden `--worker ARGS` (the arguments as JSON, as `worker`
  passes them) prints `work(ARGS)` as JSON and exits instead."""
  if work:
    p.add_argument("--worker", help=argparse.SUPPRESS)
  args = p.parse_args()
  if not getattr(args, "worker", None):
    return args
  print(json.dumps(work(argparse.Namespace(**json.loads(args.worker)))))
  sys.exit()


NOT_BEGIN = False  # a trainer's refill after a chunk (its `begin`)


class Timed:
  """`jitted(state, *args) -> (state, out)` traced and compiled (trace_s, compile_s) and called
  once to warm up. Calling this object runs it `n` times more, each call from the state the last
  left, and returns their seconds (one wait, at the end); `out` is the last call's output. With
  a `trainer`, `jitted` is its chunk, and each call refills the episode starts after it, as a
  run does."""

  def __init__(self, jitted, state, *args, trainer=None):
    start = time.perf_counter()
    lowered = jitted.lower(state, *args)
    traced = time.perf_counter()
    self.compiled = lowered.compile()
    self.trace_s, self.compile_s = traced - start, time.perf_counter() - traced
    self.refill = trainer.refill.lower(state.env, NOT_BEGIN).compile() if trainer else None
    self.state, self.args = state, args
    self()

  def __call__(self, n: int = 1) -> float:
    import jax
    start = time.perf_counter()
    for _ in range(n):
      self.state, self.out = self.compiled(self.state, *self.args)
      if self.refill is not None:
        self.state = self.state._replace(env=self.refill(self.state.env, NOT_BEGIN))
    jax.block_until_ready((self.state, self.out))
    return time.perf_counter() - start


def installed_layout(checkout: str, folder: str) -> str:
  """`checkout`'s package copied into `folder` as pyproject installs it (envs and agents inside
  mjx_hopper), for a process to run first on PYTHONPATH. Returns `folder`."""
  package = os.path.join(folder, "mjx_hopper")
  shutil.copytree(os.path.join(checkout, "mjx_hopper"), package)
  for sub in ("envs", "agents"):  # packaged as mjx_hopper.envs and .agents
    shutil.copytree(os.path.join(checkout, sub), os.path.join(package, sub))
  return folder


def project_module(dotted: str):
  """The project's module `dotted` ("run.trainers"), or in a checkout from before the floors'
  sub-packages, its flat namesake ("trainers"): for timing another checkout beside this one."""
  import importlib

  import mjx_hopper
  floors = os.path.isdir(os.path.join(mjx_hopper.__path__[0], "run"))
  return importlib.import_module("mjx_hopper." + (dotted if floors else dotted.split(".")[-1]))


def resolved(cfg):
  """`cfg`'s plan (`settings.plan.resolve`), what `trainers.build` takes; in a checkout from
  before the plan, `cfg` itself, which its `build` took."""
  try:
    return project_module("settings.plan").resolve(cfg)
  except ModuleNotFoundError:
    return cfg


def worker(script: str, args: dict, devices: int, gpus: bool = True):
  """What `python SCRIPT --worker ARGS` (`args` as JSON) prints last, as JSON, run in a process of
  its own with XLA:CPU split into `devices` devices (XLA reads its flags at start-up) and, with
  `gpus`, on the first `devices` GPUs unless CUDA_VISIBLE_DEVICES says; None if it failed."""
  import mjx_hopper  # its own imports only: JAX starts in the worker
  env = dict(os.environ, XLA_FLAGS=mjx_hopper.xla_flags_with_cpu_devices(devices))
  if gpus:
    env.setdefault("CUDA_VISIBLE_DEVICES", ",".join(map(str, range(devices))))
  done = subprocess.run([sys.executable, script, "--worker", json.dumps(args)], env=env,
                        stdout=subprocess.PIPE, text=True)
  if done.returncode:
    print(f"{os.path.basename(script)}: the worker on {devices} device(s) failed (exit "
          f"{done.returncode}): {args}", file=sys.stderr, flush=True)
    return None
  return json.loads(done.stdout.strip().splitlines()[-1])


def sweep(out_dir: str, flags: list[str], processes: int = 1, devices: int = 1,
          gpus: bool = False) -> dict:
  """`mjx-hopper sweep FLAGS` as users run it, from an empty compile cache in `out_dir`, over
  `processes` processes of `devices // processes` devices each (`--distributed` with a local
  coordinator where more than one). Returns its seconds from launch to the first train row and
  to its end ("first_row_s", "wall_s"), and the env steps/s of all members: over the train rows
  after the first, as log.csv gives them ("env_steps_per_s"), and over the whole run from
  launch ("run_env_steps_per_s")."""
  import socket

  import mjx_hopper
  with socket.socket() as free:
    free.bind(("localhost", 0))
    port = free.getsockname()[1]
  per_process, procs, files, start = devices // processes, [], [], time.perf_counter()
  for i in range(processes):
    env = dict(os.environ, XLA_FLAGS=mjx_hopper.xla_flags_with_cpu_devices(per_process),
               MJX_HOPPER_JAX_CACHE=os.path.join(out_dir, "jax_cache"), PYTHONUNBUFFERED="1")
    if gpus:
      env["CUDA_VISIBLE_DEVICES"] = ",".join(
          str(i * per_process + d) for d in range(per_process))
    distributed = ([] if processes == 1 else
                   ["--distributed", "--coordinator", f"localhost:{port}", "--num-processes",
                    str(processes), "--process-id", str(i)])
    # The first process's lines are read as they come; the others' go to files, never to a
    # pipe left unread. -P: the installed package, not a checkout's folder of the same name.
    if i:
      files.append(open(f"{out_dir}_process_{i}.txt", "w"))
    output = files[-1] if i else subprocess.PIPE
    procs.append(subprocess.Popen(
        [sys.executable, "-P", "-m", "mjx_hopper.faces.cli", "--cpu-devices", str(per_process),
         "sweep", *flags, "--out-dir", out_dir, *distributed], env=env, stdout=output,
        stderr=subprocess.STDOUT, text=True))
  first, lines = None, []
  for line in procs[0].stdout:
    lines.append(line)
    if first is None and line.startswith("[train]"):
      first = time.perf_counter() - start
  for proc in procs:
    proc.wait()
  wall = time.perf_counter() - start
  for f in files:
    f.close()
  if any(proc.returncode for proc in procs):
    raise SystemExit(f"the sweep over {processes} process(es) failed (exits "
                     f"{[proc.returncode for proc in procs]}):\n" + "".join(lines)[-3000:])
  with open(os.path.join(out_dir, "log.csv")) as f:
    rows = [r for r in csv.DictReader(f) if r["kind"] == "train"]
  rates = sorted({(int(r["env_steps"]), float(r["steps_per_s"])) for r in rows})
  later = [rate for _, rate in rates[1:]] or [rate for _, rate in rates]
  members = len({r.get("member") for r in rows})
  return {"first_row_s": first, "wall_s": wall, "env_steps_per_s": sum(later) / len(later),
          "run_env_steps_per_s": members * rates[-1][0] / wall}


def evaluations(log_csv: str) -> dict[int, list[dict]]:
  """Each member's evaluations in a run's log.csv, in order, as {EVAL_FIELDS: value}."""
  out: dict[int, list[dict]] = {}
  with open(log_csv) as f:
    for row in csv.DictReader(f):
      if row["kind"] == "eval":
        out.setdefault(int(row.get("member") or 0), []).append(
            {k: int(row[k]) if k == "env_steps" else float(row[k]) for k in EVAL_FIELDS})
  return out


def machine() -> str:
  """The GPUs (as nvidia-smi names them) and the CPU's model, widest vector unit and cores this
  process runs on."""
  try:
    gpus = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"],
                          capture_output=True, text=True).stdout.split("\n")
  except OSError:
    gpus = []
  with open("/proc/cpuinfo") as f:
    info = f.read().splitlines()
  cpu = next((l.split(":")[1].strip() for l in info if l.startswith("model name")), "a CPU")
  # One maker's CPUs of a name differ in their vector units, which set XLA:CPU's speed.
  flags = next((l.split(":")[1].split() for l in info if l.startswith("flags")), [])
  cpu += " (AVX-512)" if "avx512f" in flags else " (AVX2)" if "avx2" in flags else ""
  gpus = [g.strip() for g in gpus if g.strip()]
  return (f"{len(gpus)} x {gpus[0]}; " if gpus else "") + f"{cpu}, {os.cpu_count()} cores"


def commit() -> str:
  """The code's commit: $MJX_HOPPER_COMMIT (where the tree has no .git, as on the lent GPU), or
  git's, with "+changes" when tracked files differ from it; else "unknown"."""
  here = os.path.dirname(os.path.abspath(__file__))
  git = lambda *a: subprocess.run(["git", "-C", here, *a], capture_output=True, text=True)
  try:
    head = git("rev-parse", "--short=10", "HEAD")
  except OSError:  # no git
    head = None
  if os.environ.get("MJX_HOPPER_COMMIT") or not head or head.returncode:
    return os.environ.get("MJX_HOPPER_COMMIT", "unknown")
  return head.stdout.strip() + ("+changes" if git("status", "--porcelain", "-uno").stdout else "")


def write_results(name: str, figures, command: str | None = None) -> str:
  """`figures` as benchmarks/results/NAME.json (or in the folder $MJX_HOPPER_RESULTS names:
  gpu.sh's, which comes back from the lent GPU), beside the command line, machine, date and
  commit that made them: the form benchmarks/report.py reads. Prints and returns its path."""
  folder = os.environ.get("MJX_HOPPER_RESULTS") or os.path.join(
      os.path.dirname(os.path.abspath(__file__)), "results")
  os.makedirs(folder, exist_ok=True)
  path = os.path.join(folder, f"{name}.json")
  record = {"command": command or shlex.join(["python", *sys.argv]), "machine": machine(),
            "date": time.strftime("%Y-%m-%d"), "commit": commit(), "figures": figures}
  with open(path, "w") as f:
    json.dump(record, f, indent=1)
  print(f"results: {path}")
  return path


def table(head: list[str], rows: list[list]) -> str:
  """A markdown table: the `head` line, then each row's cells."""
  lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
  return "\n".join(lines + ["| " + " | ".join(str(c) for c in row) + " |" for row in rows])
