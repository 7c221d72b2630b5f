"""How long a training run makes a user wait: `mjx-hopper train --env ENV --agent d4pg --preset
KIND` (by default the main job's, Hopper's cpu preset) from process start to its first `[train]`
line (the first chunk done) and its first `[eval]` line, with an empty compile cache and then
with the cache that run left.

    python benchmarks/start_time.py --rounds 2
    python benchmarks/start_time.py --rounds 2 --checkout /tmp/old   # beside another checkout
    bash benchmarks/gpu.sh "python benchmarks/start_time.py --kind gpu --seconds 45 --label h100"

"first chunk starts" is the first line's time less one chunk at the run's later pace (the median
env steps/s of the rows after its first evaluation): when training began, compile done. With
--checkout DIR, DIR's mjx_hopper (laid out as installed, with its envs and agents inside, in a
temporary folder put first on PYTHONPATH) runs in turns with this one's.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

import common

STEPS = re.compile(r"\[train\] ([\d,]+) env steps \| ([\d,]+) steps/s")


def one_run(command: list[str], cache: str, code: str | None, seconds: float) -> dict:
  """Times of the main job's first lines (s from process start), run for about `seconds`."""
  env = dict(os.environ, MJX_HOPPER_JAX_CACHE=cache)
  if code:
    env["PYTHONPATH"] = os.pathsep.join([code, env.get("PYTHONPATH", "")])
  with tempfile.TemporaryDirectory() as out:
    start = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-P", *command, "--out", out,
                             "--max-minutes", str(seconds / 60)], env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    lines = [(time.perf_counter() - start, line) for line in proc.stdout]
    if proc.wait():
      raise SystemExit("the main job failed:\n" + "".join(line for _, line in lines[-20:]))
  trains = [(t, *map(lambda v: int(v.replace(",", "")), STEPS.search(line).groups()))
            for t, line in lines if line.startswith("[train]")]
  first_eval = next((t for t, line in lines if line.startswith("[eval]")), None)
  later = [rate for t, _, rate in trains if first_eval is not None and t > first_eval]
  if not later:
    raise SystemExit(f"a run of {seconds:g} s logged no chunk after its first evaluation, "
                     "whose pace the first chunk is timed by; give it more --seconds")
  pace = statistics.median(later)
  done, steps, _ = trains[0]
  return {"first_chunk_done": done, "first_chunk_starts": done - steps / pace,
          "first_eval": first_eval}


def main() -> None:
  p = argparse.ArgumentParser(description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
  p.add_argument("--rounds", type=int, default=2)
  p.add_argument("--seconds", type=float, default=75.0, help="each run's length")
  p.add_argument("--checkout", default=None, help="another checkout's folder to time beside")
  p.add_argument("--env", default="Hopper")
  p.add_argument("--kind", default="cpu", help="the robot preset: cpu or gpu")
  p.add_argument("--label", default="cpu")
  args = p.parse_args()
  command = ["-m", "mjx_hopper.cli", "train", "--env", args.env, "--agent", "d4pg", "--preset",
             args.kind, "--steps", "1000000000", "--no-progress", "--log-every", "1"]
  codes = {"this checkout": None}
  with tempfile.TemporaryDirectory(prefix="start_time_") as installed:
    if args.checkout:
      shutil.copytree(os.path.join(args.checkout, "mjx_hopper"),
                      os.path.join(installed, "mjx_hopper"))
      for sub in ("envs", "agents"):  # packaged as mjx_hopper.envs and .agents (pyproject.toml)
        shutil.copytree(os.path.join(args.checkout, sub),
                        os.path.join(installed, "mjx_hopper", sub))
      codes[args.checkout] = installed
    times = {(name, cache): [] for name in codes for cache in ("empty cache", "warm cache")}
    for i in range(args.rounds):
      for name, code in (codes.items() if i % 2 == 0 else reversed(codes.items())):
        with tempfile.TemporaryDirectory() as cache:
          for state in ("empty cache", "warm cache"):  # the second run loads what the first kept
            times[name, state].append(one_run(command, cache, code, args.seconds))
            print(name, state, times[name, state][-1], flush=True)
  fields = ("first_chunk_starts", "first_chunk_done", "first_eval")
  rows = [[name, state, *(" / ".join(f"{r[f]:.1f}" for r in runs) for f in fields)]
          for (name, state), runs in times.items()]
  text = common.table(["code", "compile cache", "first chunk starts (s)",
                       "first [train] line (s)", "first [eval] line (s)"], rows)
  print(text)
  common.write_results(f"start_time_{args.label}", {"table": text, "runs": {
      f"{name}, {state}": runs for (name, state), runs in times.items()}})


if __name__ == "__main__":
  main()
