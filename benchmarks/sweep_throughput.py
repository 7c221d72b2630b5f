"""Sweeps as users run them: `mjx-hopper sweep --seeds S` of D4PG on Hopper for each S, each in a
fresh process from an empty compile cache, timed from its launch.

    python benchmarks/sweep_throughput.py                                  # 2-core CPU
    python benchmarks/sweep_throughput.py --members 1,16,32 --gpus 1,2 --preset gpu

Each S trains --env-steps env steps per member with the preset's settings; more sweep flags
follow `--`. Records the seconds to the first train row, and the env steps/s of all members over
the train rows after the first (as log.csv gives them) and over the whole run from launch
(compile included). report.py sets them against S = 1 on the fewest devices. With --gpus 1,2
each S runs on the first GPU, then on the first two.
"""

from __future__ import annotations

import os
import sys
import tempfile

import common


def main() -> None:
  p = common.parser(__doc__)
  p.add_argument("--members", default="1,4,8", help="comma-separated sweep sizes")
  p.add_argument("--preset", default="cpu")
  p.add_argument("--env-steps", type=int, default=100_000, help="env steps per member")
  p.add_argument("--cpu-devices", type=int, default=os.cpu_count() or 1)
  p.add_argument("--gpus", help="comma-separated GPU counts: every sweep size on the first N "
                 "GPUs, for each N (default: the CPU's devices)")
  p.add_argument("--label", default="cpu",
                 help="results: benchmarks/results/sweep_throughput_LABEL.json")
  p.add_argument("extra", nargs="*", help="more sweep flags, after --")
  args = p.parse_args()
  flags = ["--env", "Hopper", "--agent", "d4pg", "--preset", args.preset, "--total-env-steps",
           str(args.env_steps), "--eval-every", str(args.env_steps), "--no-progress",
           "--log-every", "0", *args.extra]
  rows = []
  gpu_counts = [int(n) for n in args.gpus.split(",")] if args.gpus else [None]
  with tempfile.TemporaryDirectory() as tmp:
    for gpus in gpu_counts:
      devices = gpus or args.cpu_devices
      for members in [int(m) for m in args.members.split(",")]:
        run = common.sweep(os.path.join(tmp, f"g{gpus}_s{members}"),
                           [*flags, "--seeds", str(members)], devices=devices,
                           gpus=gpus is not None)
        rows.append({"members": members, "devices": devices,
                     "platform": "cpu" if gpus is None else "gpu", **run})
        print(f"  S = {members} on {devices} device(s): first row at {run['first_row_s']:.1f} "
              f"s, {run['env_steps_per_s']:,.0f} env steps/s", file=sys.stderr, flush=True)
  common.write_results(f"sweep_throughput_{args.label}", {
      "method": "mjx-hopper sweep from launch, cold",
      "settings": vars(args), "rows": rows})


if __name__ == "__main__":
  main()
