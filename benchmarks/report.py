"""BENCHMARKS.md, the README's results table and the notebook's expected times, made from the
results files in benchmarks/results/ (each: command, machine, date, commit and figures), so that
a page and its data cannot drift apart. Standard library only, and deterministic.

    python benchmarks/report.py            # write the pages
    python benchmarks/report.py --check    # exit 1 where a committed page differs
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import re
import statistics
import sys
import tomllib

from common import table

ROOT = pathlib.Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
ROBOTS = ("Hopper", "Walker2D", "HalfCheetah", "Ant", "Humanoid")
TTS = "time_to_score_{}.json"
GPU = {"Hopper": [TTS.format("Hopper_h100_cold_bf16"),
                  TTS.format("Hopper_h100_cold_bf16_seeds5-9")],
       "Walker2D": [TTS.format("Walker2D_h100_cold5_2026-11-26")],
       "HalfCheetah": [TTS.format("HalfCheetah_h100_small_batch")],
       "Ant": [TTS.format("Ant_h100_cold5_2026-11-26")],
       "Humanoid": [TTS.format("Humanoid_h100_cold5_2026-11-26")],
       "AntLongJump (an event)": [TTS.format("AntLongJump_h100")]}
CPU = {"Hopper": [TTS.format("Hopper_cpu_128")],
       "Walker2D": [TTS.format("Walker2D_cpu_tuned_2026-11-26")],
       "HalfCheetah": [TTS.format("HalfCheetah_cpu60")],
       "Ant": [TTS.format("Ant_cpu_tuned_2026-11-26")],
       "Humanoid": [TTS.format("Humanoid_cpu_tuned_2026-11-26")],
       "Hopper, DDPG": [TTS.format("Hopper_ddpg_cpu")],
       "Hopper, DMPO": [TTS.format("Hopper_dmpo128_cpu_2026-11-26")],
       "HighJump (an event)": [TTS.format("HighJump_cpu")]}
ENV = {"Hopper": "env_throughput_hopper_cpu.json", "Humanoid": "env_throughput_humanoid_cpu.json"}
ENV_OTHERS = "env_throughput_cpu_4robots.json"
PEERS = ("peers_h100.json", "peers_cpu.json")
RL_ZOO = "rl_zoo.json"
LEARNER = ("learner_robots_h100.json", "learner_robots_bf16_h100.json")
SWEEPS = ("sweep_throughput_h100.json", "sweep_throughput_2gpu_h200.json",
          "sweep_throughput_cpu.json")
PBT = "pbt_quality_halfcheetah_h100x2.json"
START = {"one H100": "start_time_h100.json", "2 CPU cores": "start_time_cpu.json"}
# A start's phases as the table shows them: label, and its key in start_time.py's medians.
START_ROWS = {"imports": "imports", "build": "build", "chunk: tracing": "chunk trace",
              "chunk: compile": "chunk compile", "init: compile": "init_member compile",
              "evaluation: compile": "one compile", "first training row": "first_train",
              "first evaluation": "first_eval", "env steps/s": "steps_per_s"}
GYMNASIUM = "gymnasium_throughput_cpu.json"
NOTEBOOK = "notebook_time_cpu_2026-11-26.json"
FIRST_VIDEO = "notebook_first_video_cpu.json"
SUITE = "suite_time_cpu.json"
TRAINERS = {"ours": "our D4PG", "sac": "Brax SAC", "ppo": "Brax PPO", "sb3": "SB3 SAC on PyBullet"}
MARK = "<!-- report.py: {} -->"


def load(name: str) -> dict:
  with open(RESULTS / name) as f:
    return json.load(f)


def num(x, digits: int = 0) -> str:
  return "-" if x is None or x == math.inf else f"{x:,.{digits}f}"


def machine(name: str) -> str:
  """A results file's machine in a few words: "1 H100", "2 H200", "2 CPU cores"."""
  text = load(name)["machine"]
  chip = next((c for c in ("H100", "H200") if c in text), None)
  if chip:
    return f"{text.split(' x ')[0]} {chip}"
  return "2 CPU cores" if "2-core" in text or text.endswith(" 2 cores") else text


def time_to_score(names: list[str], scale: float = 1.0) -> dict:
  """The seeds of `names`: how many reached the target, and the median, fastest and slowest
  time to it (divided by `scale`: 60 for minutes), a seed that missed counting as slowest."""
  figures = [load(n)["figures"] for n in names]
  runs = [s for f in figures for s in f["seeds"].values()]
  times = [math.inf if s["target_wall_s"] is None else s["target_wall_s"] / scale for s in runs]
  hit = [t for t in times if t < math.inf] or [math.inf]
  steps = [s["target_env_steps"] / 1e6 for s in runs if s["target_env_steps"]]
  return {"target": figures[0]["target"], "agent": figures[0]["agent"].upper(),
          "seeds": len(runs), "reached": sum(t < math.inf for t in times),
          "median": statistics.median(times), "fastest": min(hit), "slowest": max(hit),
          "env_steps": statistics.median(steps) if steps else None}


def score_cells(robot: str) -> list[str]:
  """A robot's score, median time and seeds reaching it: on one GPU (s), then on 2 cores (min)."""
  g, c = time_to_score(GPU[robot]), time_to_score(CPU[robot], 60)
  return [num(g["target"]), num(g["median"]), f"{g['reached']}/{g['seeds']}",
          num(c["target"]), num(c["median"], 1), f"{c['reached']}/{c['seeds']}"]


def env_rates(robot: str) -> dict:
  """PyBullet's, MuJoCo C's and MJX's best (on 2 devices) env steps/s of one robot."""
  rows = [r for r in load(ENV.get(robot, ENV_OTHERS))["figures"]["rows"] if r["env"] == robot]
  best = lambda engine, devices: max(r["env_steps_per_s"] for r in rows if r["engine"].startswith(
      engine) and r["devices"] in devices)
  return {"pybullet": best("PyBullet", (1,)), "mujoco": best("MuJoCo C", (2,)),
          "mjx": best("MJX", (2,))}


def reach(run: dict, score: int) -> float:
  return run[f"to_{score}"]["wall_s"] if run.get(f"to_{score}") else math.inf


def peer_rows(best_only: bool = False) -> list[list]:
  """A row per peers run; with `best_only`, each trainer's soonest to 2,000 (then 1,000) on each
  machine."""
  runs = [(name, run) for name in PEERS for run in load(name)["figures"]["runs"]]
  if best_only:  # the best last, so that it stays
    rank = lambda item: (reach(item[1], 2000), reach(item[1], 1000), -item[1]["best_return"])
    best = {(n, r["trainer"]): (n, r) for n, r in sorted(runs, key=rank, reverse=True)}
    runs = sorted(best.values(), key=runs.index)
  rows = []
  for name, run in runs:
    s = run["settings"]
    what = (f"reward scaling {s['reward_scaling']}, discount {s['discounting']}"
            if run["trainer"] in ("sac", "ppo") else
            "rl-zoo's" if run["trainer"] == "sb3" else "its preset")
    rows.append([machine(name), TRAINERS[run["trainer"]], what, num(reach(run, 1000)),
                 num(reach(run, 2000)), num(run["best_return"]),
                 num(run["env_steps"] / (60 * run["minutes"]))])
  return rows


PEER_HEAD = ["machine", "trainer", "settings", "to 1,000 (s)", "to 2,000 (s)", "best return",
             "env steps/s"]


def summary() -> str:
  zoo = load(RL_ZOO)["figures"]
  rows = []
  for robot in ROBOTS:
    e, published = env_rates(robot), zoo.get(robot, {})
    rows.append([robot, *score_cells(robot), num(e["mjx"] / e["pybullet"], 1),
                 num(published.get("sac")), num(published.get("tqc"))])
  return "\n\n".join([
      "Each robot's median time to its score over its seeds, compile included, from process "
      "start: on one GPU with its gpu preset, and on 2 CPU cores with its cpu preset "
      "(`mjx_hopper/presets.py`). Seeds: those that reached the score, of those run. Env steps/s "
      "× PyBullet: MJX against PyBullet on the same 2 cores. rl-baselines3-zoo's SAC and TQC "
      "scores are PyBullet's robots after 1M env steps (published, other physics: "
      f"`benchmarks/results/{RL_ZOO}`).",
      table(["robot", "GPU: score", "GPU: median (s)", "GPU: seeds", "2 cores: score",
             "2 cores: median (min)", "2 cores: seeds", "env steps/s × PyBullet",
             "rl-zoo SAC", "rl-zoo TQC"], rows),
      "Hopper beside its peers, each trainer's best settings ([all runs](#peers)):",
      table(PEER_HEAD, peer_rows(best_only=True))])


def time_section(title: str, method: str, runs: dict, unit: str, scale: float, digits: int):
  """A time-to-score section: each task's seeds, in `unit` (seconds over `scale`)."""
  rows = []
  for label, names in runs.items():
    t = time_to_score(names, scale)
    rows.append([label, num(t["target"]), t["agent"], t["seeds"], t["reached"],
                 *(num(t[k], digits) for k in ("median", "fastest", "slowest")),
                 num(t["env_steps"], 2)])
  return (title, method, table(
      ["task", "score", "agent", "seeds", "seeds reaching it", f"median ({unit})",
       f"fastest ({unit})", f"slowest ({unit})", "median env steps to it (M)"], rows),
          [n for v in runs.values() for n in v])


def sections() -> list[tuple[str, str, str, list[str]]]:
  """(title, method, table, results files) of each question after the summary."""
  out = [time_section("Time to score on one GPU", "Each robot's gpu preset alone on the GPU, "
                      "seeds one after another, each compiled afresh (`--no-compile-cache`) and "
                      "timed until an evaluation (20 episodes) reaches the score: a process's "
                      "first seed from the process's start, a later seed of the same process "
                      "from its own run's start.", GPU, "s", 1, 0),
         time_section("Time to score on 2 CPU cores", "Each robot's cpu preset (another agent: "
                      "its own preset, with the robot's settings for it where measured), seeds "
                      "one after another, compiled afresh and timed from process start, as on a "
                      "Colab CPU runtime.", CPU, "min", 60, 1),
         ("Peers", "Our D4PG beside Brax's own SAC and PPO on our Hopper, nine runs sharing one "
          "GPU for 7.5 minutes each; and Stable-Baselines3's SAC on PyBullet's Hopper (the stack "
          "of the NMA Robolympics notebook) beside our D4PG, 4 minutes each on 2 cores. Times "
          "from process start; evaluations of 16 episodes.",
          table(PEER_HEAD, peer_rows()), list(PEERS))]
  rates = {robot: env_rates(robot) for robot in ROBOTS}
  out.append(("Env throughput on 2 CPU cores", "Auto-resetting envs with random actions "
              "(observations, reward terms and resets included): MJX's best of 64, 256 and "
              "4,096 envs on 2 XLA devices; MuJoCo C rolling out the same model on 2 threads "
              "(physics only); PyBullet's own env on one core.",
              table(["robot", "PyBullet", "MuJoCo C", "MJX", "MJX × PyBullet",
                     "MJX ÷ MuJoCo C"],
                    [[robot, num(e["pybullet"]), num(e["mujoco"]), num(e["mjx"]),
                      num(e["mjx"] / e["pybullet"], 1), num(e["mjx"] / e["mujoco"], 2)]
                     for robot, e in rates.items()]),
              sorted({ENV.get(robot, ENV_OTHERS) for robot in ROBOTS})))
  f32, bf16 = (load(n)["figures"] for n in LEARNER)
  half = {r["robot"]: r["updates_per_s"] for r in bf16["rows"]}
  rows = []
  for r in f32["rows"]:
    dtype = r["overrides"].get("compute_dtype", "float32")
    peak = f32["peaks_bf16_gflops" if dtype == "bfloat16" else "peaks_gflops"]["1"]
    rows.append([r["robot"], num(r["batch"]), dtype, num(r["updates_per_s"]),
                 num(r["gflop_per_update"], 1), num(100 * r["gflops"] / peak, 1),
                 num(half.get(r["robot"]))])
  out.append(("Learner throughput on one GPU", "Each robot's gpu preset's update (its "
              "networks, batch and sizes) on random batches, 100 to a compiled scan; FLOPs as "
              "XLA counts them, against the GPU's measured matmul peak.",
              table(["robot", "batch", "precision", "updates/s", "GFLOP/update", "% of peak",
                     "bfloat16 updates/s"], rows), list(LEARNER)))
  out.append(gymnasium_section())
  out.append(start_section())
  rows = []
  for name in SWEEPS:
    found = load(name)["figures"]["rows"]
    base = min((r for r in found if r["members"] == 1), key=lambda r: r["devices"])
    rows += [[machine(name), r["devices"], r["members"], num(r["env_steps_per_s"]),
              num(r["updates_per_s"]), num(r["env_steps_per_s"] / base["env_steps_per_s"], 2)]
             for r in found]
  out.append(("Sweeps", "S seeds of D4PG on Hopper as one compiled program (`mjx-hopper "
              "sweep`), each S in a fresh process; × one run: their env steps/s over one "
              "member's on one device of the same machine.",
              table(["machine", "devices", "members", "env steps/s", "updates/s", "× one run"],
                    rows), list(SWEEPS)))
  out.append(("Population-based training", "HalfCheetah, 16 members (4 learning rates × 4 "
              "noise scales), a grid and PBT side by side on each GPU for the same 15.6 "
              "minutes; PBT steps at every second evaluation.",
              table(["seed", "run", "3,000 first at (s)", "best return", "members' median best",
                     "env steps per member", "env steps/s"], load(PBT)["figures"]["rows"]),
              [PBT]))
  nb = load(NOTEBOOK)["figures"]
  out.append(("The notebook on 2 CPU cores", "`notebooks/robolympics.ipynb` in its full mode, "
              "top to bottom, from an empty compile cache (sections under half a minute left "
              "out), and its first video (the pretrained Humanoid) from the kernel's start.",
              table(["section", "minutes"], [[t, num(s / 60, 1)] for t, s in
                                             nb["sections_s"].items() if s >= 30]
                    + [["all", num(nb["total_s"] / 60, 1)], ["first video", num(
                        load(FIRST_VIDEO)["figures"]["first_video_s"] / 60, 1)]]),
              [NOTEBOOK, FIRST_VIDEO]))
  out.append(pretrained_section(sorted(p.name for p in RESULTS.glob("pretrained_*.json"))))
  suite = load(SUITE)["figures"]
  out.append(("Test suite", "`bash scripts/test.sh`, as CI runs it, on 2 CPU cores from an "
              "empty compile cache.",
              table(["tests passed", "failed", "pytest (min)", "with set-up (min)"],
                    [[suite["passed"], suite["failed"], num(suite["pytest_s"] / 60, 1),
                      num(suite["with_setup_s"] / 60, 1)]]), [SUITE]))
  return out


def start_section() -> tuple[str, str, str, list[str]]:
  """A run's start, phase by phase (s from process start), before and after, cold and warm."""
  tables = []
  for where, name in START.items():
    data, columns = load(name), {}
    for label, figures in data["figures"]["medians"].items():
      code, cache = label.split(", ")
      code = data["commit"] if code == "this checkout" else code
      flags = data["figures"].get("xla_flags")
      columns[f"{code}{' with ' + flags if flags else ''}, {cache}"] = figures
    rows = [[label, *("–" if c.get(key) is None else num(c[key], 0 if key == "steps_per_s" else 1)
                      for c in columns.values())] for label, key in START_ROWS.items()]
    tables.append(f"On {where}:\n\n" + table(["phase (s)", *columns], rows))
  return ("The start, phase by phase", "The main job's command (Hopper: gpu preset on the GPU, "
          "cpu on 2 cores), seconds from process start, cold (an empty compile cache) and warm "
          "(the one it left), beside 416e724; compiles overlap.",
          "\n\n".join(tables), list(START.values()))


def pretrained_section(names: list[str]) -> tuple[str, str, str, list[str]]:
  """The shipped policies (mjx_hopper/pretrained/): how each was trained, and its file's return."""
  rows = []
  for name in names:
    r = load(name)["figures"]
    rows.append([r["robot"], num(r["target"]), r["seed"], num(r["env_steps"]),
                 num(r["wall_s"]), num(r["best_eval_return"]),
                 f"{num(r['return'])} ± {num(r['return_std'])}", num(r["file_bytes"] / 1024)])
  return ("Pretrained policies", "One policy per robot in `mjx_hopper/pretrained/`: its gpu "
          "preset trained until an evaluation reached its score plus a margin, the best policy "
          "exported, and the file evaluated again (`benchmarks/pretrain.py`).",
          table(["robot", "score", "seed", "env steps", "training (s)", "best evaluation",
                 "the file's return", "file (KiB)"], rows), names)


def gymnasium_section() -> tuple[str, str, str, list[str]]:
  """The Gymnasium door's env steps/s against the JAX env's."""
  figures = load(GYMNASIUM)["figures"]
  jax_rate = figures["rows"][0]["env_steps_per_s"]
  rows = [[r["engine"], num(r["num_envs"]), num(r["env_steps_per_s"]),
           num(r["env_steps_per_s"] / jax_rate, 2)] for r in figures["rows"]]
  return ("The Gymnasium door on 2 CPU cores", "Hopper with random actions through "
          "`envs.to_gymnasium` (NumPy in and out, a jit-compiled step per call) against the JAX "
          "env's compiled scan, timed in turns in one process.",
          table(["engine", "envs", "env steps/s", "× JAX env"], rows), [GYMNASIUM])


def code(commit: str) -> str:
  """A results file's code commit as its source line gives it; an older file that does not know
  it says the commit that filed its results ("unknown; results committed in C")."""
  unknown = "unknown; "
  return commit.removeprefix(unknown) if commit.startswith(unknown) else f"commit {commit}"


def benchmarks_page() -> str:
  parts = ["# Benchmarks", "Made by `python benchmarks/report.py` from `benchmarks/results/`, "
           "whose files each hold their command, machine, date, code commit and figures; do not "
           "edit by hand. The machines are shared and noisy: compare rows of one run.",
           "## Summary", summary()]
  for title, method, text, names in sections():
    sources = [f"- `benchmarks/results/{n}` ({r['date']}, {machine(n)}, {code(r['commit'])}): "
               f"`{r['command']}`" for n, r in ((n, load(n)) for n in dict.fromkeys(names))]
    parts += [f"## {title}", method, text, "Results, and the commands that made them:\n\n"
              + "\n".join(sources)]
  return "\n\n".join(parts) + "\n"


def readme_table() -> str:
  rows = [[f'<img src="{media()}/{robot}.gif" width="160">', robot, *score_cells(robot)]
          for robot in ROBOTS]
  return table(["", "robot", "score (GPU)", f"median on {machine(GPU['Hopper'][0])} (s)",
                "seeds reaching it", "score (2 cores)", "median on 2 CPU cores (min)",
                "seeds reaching it"], rows)


def media() -> str:
  """Where the README's images are: absolute, on the repository of pyproject's project.urls, so
  that they load where the README is shown outside it (PyPI); relative while that address is
  the placeholder."""
  with open(ROOT / "pyproject.toml", "rb") as f:
    repository = tomllib.load(f)["project"]["urls"]["Repository"]
  return "docs/media" if "/OWNER/" in repository else f"{repository}/raw/main/docs/media"


def notebook_times() -> str:
  nb = load(NOTEBOOK)["figures"]
  rows = [[t, f"{s / 60:.0f}"] for t, s in nb["sections_s"].items() if s >= 60]
  return (f"**How long.** On a 2-core machine the whole notebook ran in "
          f"{nb['total_s'] / 60:.0f} minutes, compile included, most of it in these sections:\n\n"
          + table(["section", "minutes"], rows) + "\n\nColab's CPUs may be slower: each "
          "training cell stops at its time budget.")


def splice(text: str, key: str, block: str) -> str:
  """`text` with what lies between its pair of `key` markers replaced by `block`."""
  begin, end = MARK.format(key), MARK.replace("<!-- ", "<!-- /").format(key)
  pattern = re.compile(re.escape(begin) + ".*?" + re.escape(end), re.S)
  if not pattern.search(text):
    raise SystemExit(f"report.py: no {begin} ... {end} markers to write between")
  return pattern.sub(lambda _: f"{begin}\n{block}\n{end}", text)


def pages() -> dict[pathlib.Path, str]:
  """Each page's path and the text the results make of it."""
  readme, notebook_path = ROOT / "README.md", ROOT / "notebooks" / "robolympics.ipynb"
  notebook = json.loads(notebook_path.read_text())
  cells = [c for c in notebook["cells"] if MARK.format("times") in "".join(c["source"])]
  if len(cells) != 1:
    raise SystemExit(f"report.py: want one notebook cell with {MARK.format('times')}")
  cells[0]["source"] = splice("".join(cells[0]["source"]), "times",
                              notebook_times()).splitlines(keepends=True)
  return {ROOT / "BENCHMARKS.md": benchmarks_page(),
          readme: splice(readme.read_text(), "results", readme_table()),
          notebook_path: json.dumps(notebook, indent=1, ensure_ascii=False) + "\n"}


def used_files() -> set[str]:
  """Every results file the pages are made from."""
  return {n for *_, names in sections() for n in names} | {RL_ZOO}


def main() -> None:
  p = argparse.ArgumentParser(description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
  p.add_argument("--check", action="store_true",
                 help="write nothing; exit 1 if a page differs from what the results make")
  args = p.parse_args()
  made = pages()
  stale = [path for path, text in made.items() if path.read_text() != text]
  if args.check and stale:
    sys.exit(f"report.py --check: {', '.join(str(p.relative_to(ROOT)) for p in stale)} differ "
             "from what benchmarks/results/ makes; run python benchmarks/report.py")
  for path in stale:
    path.write_text(made[path])
  print(f"wrote {len(stale)} page(s)" if stale and not args.check else "up to date")


if __name__ == "__main__":
  main()
