"""The Robolympics notebook in its full mode (MJX_HOPPER_SHORT unset), executed top to bottom as a
Colab user runs it, with each section's wall-clock time (its first cell's start to its last's end)
and each run's score: its best evaluation against the return it stops at.

    python benchmarks/notebook_time.py --out runs/notebook_full

Runs in OUT with an empty compile cache (OUT/jax_cache, refused where it or OUT/runs holds
anything), in this interpreter's kernel, which has the project: the install cell finds it
installed, so its time leaves out an install. With --fresh-venv PYTHON it runs as on a new
runtime instead: from a clone of this checkout's HEAD (OUT/mjx_hopper/notebooks, so that the
install cell finds the repository at ".."), in the kernel of a new venv of PYTHON that holds
Jupyter's kernel alone (as a runtime does before the notebook; not timed), with pip's cache off:
the install cell downloads and installs the project and its dependencies, and is timed. Keeps
OUT/robolympics.ipynb; the times go to benchmarks/results/notebook_time_LABEL.json. With
--first-video it stops after the first cell that films (a newcomer's first wait), and writes
notebook_first_video_LABEL.json.
"""

from __future__ import annotations

import datetime
import json
import os
import pathlib
import subprocess
import time

import common

NOTEBOOK = pathlib.Path(__file__).parent.parent / "notebooks" / "robolympics.ipynb"


def seconds(cell) -> tuple[float, float] | None:
  """(start, end) of a code cell's execution, as nbclient recorded it."""
  timing = cell.get("metadata", {}).get("execution", {})
  if "iopub.execute_input" not in timing or "shell.execute_reply" not in timing:
    return None
  parse = lambda t: datetime.datetime.fromisoformat(t.replace("Z", "+00:00")).timestamp()
  return parse(timing["iopub.execute_input"]), parse(timing["shell.execute_reply"])


def one_clock(evals: list[dict]) -> list[dict]:
  """A member's evaluations, in order, with a resumed run's clock (which starts again at 0)
  continued from the last evaluation before it: the seconds it trained in all."""
  out, offset, last = [], 0.0, 0.0
  for e in evals:
    if e["wall_s"] < last:
      offset += last
    last = e["wall_s"]
    out.append({**e, "wall_s": e["wall_s"] + offset})
  return out


def scores(runs: str) -> dict[str, dict]:
  """Each run the notebook trained (a folder of `runs`): the return it stops at (None: it
  trains its budget), its best evaluation (a population's best member's), its env steps, and the
  seconds it had trained (`one_clock`) at the evaluation that first reached its score (None:
  none did)."""
  out = {}
  for name in sorted(os.listdir(runs)):
    log, config = (os.path.join(runs, name, f) for f in ("log.csv", "config.json"))
    if not os.path.exists(log):
      continue
    with open(config) as f:
      target = json.load(f)["stop_at_return"]
    evals = [e for member in common.evaluations(log).values() for e in one_clock(member)]
    first = min((e for e in evals if target is not None and e["eval_return"] >= target),
                key=lambda e: e["env_steps"], default=None)
    out[name] = {"target": target,
                 "best_return": round(max(e["eval_return"] for e in evals), 1),
                 "env_steps": max(e["env_steps"] for e in evals),
                 "target_wall_s": round(first["wall_s"], 1) if first else None}
  return out


def fresh_kernel(out: str, python: str) -> tuple[str, str]:
  """A clone of this checkout's HEAD in OUT/mjx_hopper, and a new venv of PYTHON in OUT/venv with
  ipykernel alone, registered as the kernel "fresh" under OUT/jupyter: the notebook's folder
  in the clone, and the kernel's name."""
  clone, venv = os.path.join(out, "mjx_hopper"), os.path.join(out, "venv")
  if os.path.exists(clone) or os.path.exists(venv):
    raise SystemExit(f"notebook_time: {out} holds an earlier fresh run: choose another --out")
  run = lambda *command: subprocess.run(command, check=True)
  run("git", "clone", "--quiet", str(NOTEBOOK.parent.parent), clone)
  run(python, "-m", "venv", venv)
  run(os.path.join(venv, "bin", "python"), "-m", "pip", "install", "--quiet", "ipykernel")
  run(os.path.join(venv, "bin", "python"), "-m", "ipykernel", "install", "--prefix",
      os.path.join(out, "jupyter"), "--name", "fresh")
  os.environ["JUPYTER_PATH"] = os.path.join(out, "jupyter", "share", "jupyter")
  os.environ["PIP_NO_CACHE_DIR"] = "1"  # the install cell downloads, as on a new runtime
  return os.path.join(clone, "notebooks"), "fresh"


def main() -> None:
  p = common.parser(__doc__)
  p.add_argument("--out", default="runs/notebook_full")
  p.add_argument("--timeout", type=int, default=3600, help="seconds a cell may take")
  p.add_argument("--label", default="cpu")
  p.add_argument("--first-video", action="store_true",
                 help="run up to the first cell that writes a video, and time it")
  p.add_argument("--fresh-venv", metavar="PYTHON",
                 help="run from a clone, in a new venv of PYTHON, timing the notebook's install")
  args = p.parse_args()
  import nbformat
  from nbclient import NotebookClient

  for left in ("jax_cache", "runs"):  # an earlier run's programs or checkpoints
    path = os.path.join(args.out, left)
    if os.path.isdir(path) and os.listdir(path):
      raise SystemExit(f"notebook_time: {args.out}/{left} is not empty: choose another --out, "
                       "as the notebook would load or resume what it holds")
  os.makedirs(args.out, exist_ok=True)
  folder, kernel = (fresh_kernel(args.out, args.fresh_venv) if args.fresh_venv
                    else (args.out, "python3"))
  os.environ.pop("MJX_HOPPER_SHORT", None)
  os.environ["MJX_HOPPER_JAX_CACHE"] = os.path.abspath(os.path.join(args.out, "jax_cache"))
  notebook = nbformat.read(pathlib.Path(folder, NOTEBOOK.name) if args.fresh_venv else NOTEBOOK,
                           as_version=4)
  films = [i for i, c in enumerate(notebook.cells) if c.cell_type == "code" and ".mp4" in c.source]
  if args.first_video:
    notebook.cells = notebook.cells[:films[0] + 1]
  start = time.time()
  try:
    NotebookClient(notebook, timeout=args.timeout, kernel_name=kernel,
                   resources={"metadata": {"path": folder}}).execute()
  finally:
    nbformat.write(notebook, os.path.join(args.out, "robolympics.ipynb"))
  total = time.time() - start
  sections, title = {}, "before section 1"
  for cell in notebook.cells:
    if cell.cell_type == "markdown" and cell.source.startswith("## "):
      title = cell.source.splitlines()[0][3:]
    elif cell.cell_type == "code" and seconds(cell):
      first, last = seconds(cell)
      sections[title] = (sections.get(title, (first,))[0], last)  # the first cell's start
  seconds_ = {title: round(ended - begun, 1) for title, (begun, ended) in sections.items()}
  first_video = round(seconds(notebook.cells[films[0]])[1] - start, 1)
  print(f"the notebook in {total / 60:.1f} min; its first video after {first_video:.0f} s")
  print(common.table(["section", "wall-clock (s)"],
                     [[t, f"{s:,.0f}"] for t, s in seconds_.items()]))
  figures = {"total_s": round(total, 1), "first_video_s": first_video, "sections_s": seconds_,
             "install": "timed, from a new venv" if args.fresh_venv else "none (installed)"}
  if not args.first_video:
    figures["runs"] = scores(os.path.join(folder, "runs"))
    print(common.table(["run", "stops at", "best evaluation", "reached after (s)"],
                       [[n, r["target"], f"{r['best_return']:,.0f}", r["target_wall_s"]]
                        for n, r in figures["runs"].items()]))
  name = "notebook_first_video" if args.first_video else "notebook_time"
  common.write_results(f"{name}_{args.label}", figures)


if __name__ == "__main__":
  main()
