"""One sweep over P processes (JAX's distributed runtime) against one process with all devices.

    python benchmarks/distributed.py --devices 2                          # CPU: 2 devices
    python benchmarks/distributed.py --devices 2 --gpus                   # 2 GPUs of one host

Runs `mjx-hopper sweep` twice: one process on --devices devices, then --devices processes of
one device each (`--distributed`, a local coordinator), each from an empty compile cache of
its own. Records the time from the launch to the first train row, and the env steps/s (all
members) of the train rows after the first, as log.csv gives them. Extra sweep flags follow `--`.
"""

from __future__ import annotations

import os
import tempfile

import common

SWEEP = ["--env", "Hopper", "--preset", "cpu", "--seeds", "4", "--total-env-steps", "200000",
         "--eval-every", "100000", "--no-progress", "--log-every", "0"]


def main() -> None:
  p = common.parser(__doc__)
  p.add_argument("--devices", type=int, default=2, help="devices in all (and processes)")
  p.add_argument("--gpus", action="store_true", help="GPUs, one per process")
  p.add_argument("extra", nargs="*", help="more sweep flags, after --")
  args = p.parse_args()
  figures = []
  with tempfile.TemporaryDirectory() as tmp:
    for processes in (1, args.devices):
      run = common.sweep(os.path.join(tmp, f"p{processes}"), SWEEP + args.extra, processes,
                         args.devices, args.gpus)
      figures.append({"processes": processes, "devices": args.devices,
                      "platform": "gpu" if args.gpus else "cpu",
                      "first_row_s": round(run["first_row_s"], 1),
                      "env_steps_per_s": round(run["env_steps_per_s"])})
      print(figures[-1], flush=True)
  common.write_results(f"distributed_{'gpu' if args.gpus else 'cpu'}{args.devices}", figures)


if __name__ == "__main__":
  main()
