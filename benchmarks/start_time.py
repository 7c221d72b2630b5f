"""How long a training run makes a user wait, phase by phase: `mjx-hopper train --env ENV --agent
d4pg --preset KIND` from process start to its first `[train]` and `[eval]` lines, from an empty
compile cache ("cold") and then from the cache that run left ("warm"). Each run records, in
seconds from process start: the imports, the build (imports done to the chunk's tracing), each
program's tracing, lowering and XLA compile (`jax.monitoring`'s events), and the first lines.
With --checkout DIR, DIR's code (laid out as installed, first on PYTHONPATH) runs in turns with
this one's; with --python PYTHON, this code on another interpreter and its releases (JAX's).

    python benchmarks/start_time.py --rounds 2 --checkout /tmp/before   # beside another commit
    python benchmarks/start_time.py --python .venv-floor/bin/python      # beside the floor's JAX
    python benchmarks/start_time.py --physics mjx,c                      # MJX beside MuJoCo C
    bash benchmarks/gpu.sh "python benchmarks/start_time.py --kind gpu --label h100"
"""

from __future__ import annotations

import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time

import common

# Runs in the measured process: JAX's compile events with their end times, then the CLI.
PROBE = """
import atexit, json, sys, time
import jax
events = []
def listen(event, duration, fun_name="?", **kwargs):
  events.append((time.time(), event.rsplit("/", 1)[-1], fun_name, duration))
jax.monitoring.register_event_duration_secs_listener(listen)
sys.path.insert(0, sys.argv[1])  # benchmarks/, for common.project_module
import common
common.project_module("run.loop")
cli = common.project_module("faces.cli")
imported = time.time()
record = sys.argv[2]
atexit.register(lambda: json.dump({"imported": imported, "events": events}, open(record, "w")))
sys.argv = ["mjx-hopper"] + sys.argv[3:]
cli.main()
"""
PHASES = {"jaxpr_trace_duration": "trace", "jaxpr_to_mlir_module_duration": "lower",
          "backend_compile_duration": "compile"}
RATE = re.compile(r"\| ([\d,]+) steps/s")
MIN_SECONDS = 0.2  # programs whose phases took less are summed as "small programs"


def one_run(command: list[str], cache: str, python: str, code: str | None,
            seconds: float) -> dict:
  """One run's phases (s from process start), run for about `seconds`."""
  env = dict(os.environ, MJX_HOPPER_JAX_CACHE=cache)
  if code:
    env["PYTHONPATH"] = os.pathsep.join([code, env.get("PYTHONPATH", "")])
  with tempfile.TemporaryDirectory() as out:
    record = os.path.join(out, "events.json")
    start = time.time()
    proc = subprocess.Popen([python, "-P", "-c", PROBE,
                             os.path.dirname(os.path.abspath(__file__)), record, *command,
                             "--out-dir", out, "--max-minutes", str(seconds / 60)], env=env,
                            text=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    lines = [(time.time() - start, line) for line in proc.stdout]
    if proc.wait():
      raise SystemExit("the run failed:\n" + "".join(line for _, line in lines[-20:]))
    with open(record) as f:
      probe = json.load(f)
  first = {kind: next((t for t, line in lines if line.startswith(f"[{kind}]")), None)
           for kind in ("train", "eval")}
  # Training's pace once started: the rows after the first evaluation (which competes with the
  # first chunks for the CPU).
  later = [float(RATE.search(line).group(1).replace(",", "")) for t, line in lines
           if line.startswith("[train]") and t > (first["eval"] or float("inf"))]
  programs: dict[str, dict[str, float]] = {}
  chunk_traced = None
  for end, event, name, duration in probe["events"]:
    if event not in PHASES:
      continue
    name = name.removeprefix("jit(").removesuffix(")")
    if name == "chunk" and event == "jaxpr_trace_duration" and chunk_traced is None:
      chunk_traced = end - duration - start
    if end - start <= (first["eval"] or float("inf")):  # what the first evaluation waited for
      phases = programs.setdefault(name, {})
      phases[PHASES[event]] = phases.get(PHASES[event], 0.0) + duration
  small = {k: v for k, v in programs.items() if sum(v.values()) < MIN_SECONDS}
  programs = {k: v for k, v in programs.items() if k not in small}
  programs[f"{len(small)} small programs"] = {
      phase: sum(v.get(phase, 0.0) for v in small.values()) for phase in PHASES.values()}
  imported = probe["imported"] - start
  return {"imports": imported, "build": (chunk_traced or imported) - imported,
          "first_train": first["train"], "first_eval": first["eval"],
          "steps_per_s": statistics.median(later) if later else None, "programs": programs}


def versions(python: str) -> str:
  """The interpreter's Python and JAX versions, as "Python 3.12.1, jax 0.12.0"."""
  return subprocess.run([python, "-c", "import sys, jax; print(f'Python "
                         "{sys.version.split()[0]}, jax {jax.__version__}')"], check=True,
                        capture_output=True, text=True).stdout.strip()


def summary(runs: list[dict]) -> dict:
  """The medians of `runs`' phases, programs' phases flattened as 'PROGRAM PHASE'."""
  def flat(run):
    out = {k: run[k] for k in ("imports", "build", "first_train", "first_eval", "steps_per_s")}
    for program, phases in run["programs"].items():
      out.update({f"{program} {phase}": s for phase, s in phases.items()})
    return out
  flats = [flat(r) for r in runs]
  keys = [k for k in flats[0] if all(f.get(k) is not None for f in flats)]
  return {k: statistics.median(f[k] for f in flats) for k in keys}


def main() -> None:
  p = common.parser(__doc__)
  p.add_argument("--rounds", type=int, default=2)
  p.add_argument("--seconds", type=float, default=60.0, help="each run's length")
  p.add_argument("--checkout", default=None, help="another checkout's folder to time beside")
  p.add_argument("--checkout-name", default=None,
                 help="its name in the results, such as its commit (default: its folder)")
  p.add_argument("--python", default=None,
                 help="another interpreter, with its own releases, to time this code on beside")
  p.add_argument("--env", default="Hopper")
  p.add_argument("--kind", default="cpu", help="the robot preset: cpu or gpu")
  p.add_argument("--physics", default="mjx",
                 help="this checkout's physics engines, in turns: mjx, c, or mjx,c")
  p.add_argument("--label", default="cpu")
  args = p.parse_args()
  command = ["train", "--env", args.env, "--agent", "d4pg", "--preset", args.kind,
             "--total-env-steps", "1000000000", "--no-progress", "--log-every", "1"]
  released = {python: versions(python) for python in (sys.executable, args.python) if python}
  # name: (interpreter, code's folder (None: this checkout), the train command's added flags)
  codes = {("this checkout" if physics == "mjx" else f"this checkout, --physics {physics}"):
           (sys.executable, None, [] if physics == "mjx" else ["--physics", physics])
           for physics in args.physics.split(",")}
  with tempfile.TemporaryDirectory(prefix="start_time_") as installed:
    if args.checkout:
      codes[args.checkout_name or args.checkout] = (
          sys.executable, common.installed_layout(args.checkout, installed), [])
    if args.python:
      codes[f"this checkout on {released[args.python]}"] = (args.python, None, [])
    runs = {(name, cache): [] for name in codes for cache in ("cold", "warm")}
    for i in range(args.rounds):
      for name, (python, code, flags) in (codes.items() if i % 2 == 0
                                          else reversed(codes.items())):
        with tempfile.TemporaryDirectory() as cache:
          for state in ("cold", "warm"):  # the second run loads what the first kept
            runs[name, state].append(one_run(command + flags, cache, python, code,
                                             args.seconds))
            print(name, state, json.dumps(runs[name, state][-1]), flush=True)
  medians = {f"{name}, {state}": summary(r) for (name, state), r in runs.items()}
  for label, figures in medians.items():
    print(label, {k: round(v, 1) for k, v in figures.items()})
  common.write_results(f"start_time_{args.label}", {
      "preset": f"{args.env} {args.kind}", "xla_flags": os.environ.get("XLA_FLAGS"),
      "versions": {name: released[python] for name, (python, _, _) in codes.items()},
      "medians": medians,
      "runs": {f"{name}, {state}": r for (name, state), r in runs.items()}})


if __name__ == "__main__":
  main()
