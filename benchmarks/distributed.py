"""One sweep over P processes (JAX's distributed runtime) against one process with all devices.

    python benchmarks/distributed.py --devices 2                          # CPU: 2 devices
    python benchmarks/distributed.py --devices 2 --gpus                   # 2 GPUs of one host

Runs `mjx-hopper sweep` twice: one process on --devices devices, then --devices processes of
one device each (`--distributed`, a local coordinator), each from an empty compile cache of
its own. Records the time from the launch to the first train row, and the env steps/s (all
members) of the train rows after the first, as log.csv gives them. Extra sweep flags follow `--`.
"""

from __future__ import annotations

import csv
import os
import socket
import subprocess
import sys
import tempfile
import time

import common

SWEEP = ["--env", "Hopper", "--preset", "cpu", "--seeds", "4", "--total-env-steps", "200000",
         "--eval-every", "100000", "--no-progress", "--log-every", "0"]


def launch(out_dir: str, processes: int, devices: int, gpus: bool, extra: list[str]):
  """(seconds to the first train row, mean env steps/s after it) of one sweep."""
  import mjx_hopper
  port = _free_port()
  procs = []
  start = time.perf_counter()
  per_process = devices // processes
  for i in range(processes):
    env = dict(os.environ, XLA_FLAGS=mjx_hopper.xla_flags_with_cpu_devices(per_process),
               MJX_HOPPER_JAX_CACHE=os.path.join(out_dir, "jax_cache"))  # cold, each sweep
    if gpus:
      env["CUDA_VISIBLE_DEVICES"] = ",".join(
          str(i * per_process + d) for d in range(per_process))
    flags = ([] if processes == 1 else
             ["--distributed", "--coordinator", f"localhost:{port}", "--num-processes",
              str(processes), "--process-id", str(i)])
    procs.append(subprocess.Popen(
        [sys.executable, "-m", "mjx_hopper.faces.cli", "--cpu-devices", str(per_process), "sweep",
         *SWEEP, *extra, "--out-dir", out_dir, *flags], env=env, stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT, text=True))
  first = None
  for line in procs[0].stdout:
    if first is None and line.startswith("[train]"):
      first = time.perf_counter() - start
  for proc in procs:
    proc.wait()
    if proc.returncode:
      raise SystemExit(f"the sweep over {processes} process(es) failed (exit "
                       f"{proc.returncode}); see {out_dir}")
  with open(os.path.join(out_dir, "log.csv")) as f:
    rates = sorted({(int(r["env_steps"]), float(r["steps_per_s"]))
                    for r in csv.DictReader(f) if r["kind"] == "train"})
  later = [rate for _, rate in rates[1:]] or [rate for _, rate in rates]
  return first, sum(later) / len(later)


def _free_port() -> int:
  with socket.socket() as s:
    s.bind(("localhost", 0))
    return s.getsockname()[1]


def main() -> None:
  p = common.parser(__doc__)
  p.add_argument("--devices", type=int, default=2, help="devices in all (and processes)")
  p.add_argument("--gpus", action="store_true", help="GPUs, one per process")
  p.add_argument("extra", nargs="*", help="more sweep flags, after --")
  args = p.parse_args()
  figures = []
  with tempfile.TemporaryDirectory() as tmp:
    for processes in (1, args.devices):
      first, rate = launch(os.path.join(tmp, f"p{processes}"), processes, args.devices,
                           args.gpus, args.extra)
      figures.append({"processes": processes, "devices": args.devices,
                      "platform": "gpu" if args.gpus else "cpu",
                      "first_row_s": round(first, 1), "env_steps_per_s": round(rate)})
      print(figures[-1], flush=True)
  common.write_results(f"distributed_{'gpu' if args.gpus else 'cpu'}{args.devices}", figures)


if __name__ == "__main__":
  main()
