"""BENCHMARKS.md, the README's results table, the notebook's expected times and docs/fidelity.md's
table, made from the results files in benchmarks/results/ (each: command, machine, date, commit
and figures), so that a page and its data cannot drift apart. Standard library only, and
deterministic.

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
GPU = {"Hopper": [TTS.format("Hopper_gpu_heldout3")],
       **{robot: [TTS.format(f"{robot}_gpu_heldout{n}") for n in ("", "2", "3")]
          for robot in ROBOTS[1:]},
       "AntLongJump (an event)": [TTS.format(f"AntLongJump_gpu_heldout{n}")
                                  for n in ("", "2", "3")]}
CPU = {"Hopper": [TTS.format("Hopper_cpu_heldout_avx2")],
       "Walker2D": [TTS.format("Walker2D_cpu_heldout")],
       "HalfCheetah": [TTS.format(f"HalfCheetah_cpu_heldout{n}") for n in ("", "2", "3")],
       "Ant": [TTS.format("Ant_cpu_heldout")],
       "Humanoid": [TTS.format(f"Humanoid_cpu_heldout{n}") for n in ("", "2", "3")],
       "Hopper, DDPG": [TTS.format("Hopper_cpu_ddpg_heldout_avx2")],
       "Hopper, DMPO": [TTS.format("Hopper_cpu_dmpo_heldout_avx2")],
       "HighJump (an event)": [TTS.format("HighJump_cpu_heldout")]}
ENV = {"Hopper": "env_throughput_hopper_cpu.json", "Humanoid": "env_throughput_humanoid_cpu.json"}
ENV_OTHERS = "env_throughput_cpu_4robots.json"
PEERS = ("peers_h100.json", "peers_cpu.json")
RL_ZOO = "rl_zoo.json"
LEARNER = ("learner_robots_h100.json", "learner_robots_bf16_h100.json")
# The Hopper's cpu preset's learner at other batch sizes, and one change to the preset timed to
# its score beside it (issue 69's cheaper CPU learner).
LEARNER_CPU = "learner_throughput_cpu_batches.json"
# The Hopper's cpu preset's learner with a cheaper critic, in one session beside the preset.
LEARNER_CPU_CRITICS = {"none": "learner_throughput_cpu_base.json",
                       "num_atoms=21": "learner_throughput_cpu_atoms21.json",
                       "critic_layers=(64, 64)": "learner_throughput_cpu_critic64.json"}
LEARNER_CHANGES_CPU = [{"baseline": [TTS.format("Hopper_cpu_v_cpu_base")],
                        "batch1024": [TTS.format("Hopper_cpu_v_cpu_batch1024")]}]
SWEEPS = ("sweep_throughput_h100.json", "sweep_throughput_cpu.json")
SWEPT = "mjx-hopper sweep from launch, cold"  # sweep_throughput.py's method
PBT = "pbt_quality_halfcheetah_h100x2.json"
# The main job's start on each machine: each file's own code, cold and warm (a file's other
# checkout, the before of an earlier change, stays in the file).
START = ("start_time_h200.json", "start_time_h100.json", "start_time_cpu.json")
# The sweeps over processes, and where each file's sweeps compiled: distributed.py gives each an
# empty cache of its own since 3f0a8f6; the 2-GPU file is older (no 2-GPU machine since).
DISTRIBUTED = {"distributed_gpu2.json": "the user's default, not emptied",
               "distributed_cpu2.json": "empty, each its own"}
# A start's phases as the table shows them: label, and its keys in start_time.py's medians (the
# first found: the evaluation's program was "one" before it was kept as "evaluate").
START_ROWS = {"imports": ("imports",), "build": ("build",), "chunk: tracing": ("chunk trace",),
              "chunk: compile": ("chunk compile",), "init: compile": ("init_member compile",),
              "refill: compile": ("refill compile",),
              "evaluation: compile": ("evaluate compile", "one compile"),
              "first training row": ("first_train",), "first evaluation": ("first_eval",),
              "env steps/s": ("steps_per_s",)}
GYMNASIUM = "gymnasium_throughput_cpu.json"
NOTEBOOK = "notebook_time_cpu.json"
# The notebook's single high jump trains seed 0 (a tuning seed) for 1.5 times this run's need.
NOTEBOOK_JUMP = TTS.format("HighJump_cpu_notebook_seed")
FIDELITY = "fidelity.json"
# Where a chunk's time goes: the Hopper's cpu preset with each choice of CPU matrix kernels, and
# the gpu presets of the Hopper and the Humanoid (whose physics is the largest share).
ITERATION = {"Hopper cpu, XLA's": "cpu_iteration_cpu.json",
             "Hopper cpu, YNNPACK's": "cpu_iteration_cpu_ynn.json",
             "Hopper gpu": "cpu_iteration_gpu_hopper_h100.json",
             "Humanoid gpu": "cpu_iteration_gpu_humanoid_h100.json"}
# CI's jobs in its order.
SUITE = {"suite_time_quick.json": "`scripts/test.sh`",
         "suite_time_slow.json": "`scripts/test.sh -m slow`",
         "suite_time_floor_py311.json": "`.ci/floor`"}
# The tiers' results files, for the seconds of each test file.
SUITE_FILES = {"quick": "suite_time_quick.json", "slow": "suite_time_slow.json"}
HEAVIEST_FILES = 3
COMPILE_FLAGS = "compile_flags_cpu.json"
C_PHYSICS = "c_physics_cpu.json"
WARP = "warp_physics_h100.json"  # MJX's JAX and Warp physics on one GPU
# Robots' cpu presets trained with each physics engine (--physics), one after the other; and the
# Hopper's start with each, in turns (start_time.py's names for them).
PHYSICS_TTS = {"Hopper": {"MJX": TTS.format("Hopper_cpu_mjx_after_c"),
                          "MuJoCo C": TTS.format("Hopper_cpu_c_physics")}}
PHYSICS_START = ("start_time_cpu_physics.json",
                 {"MJX": "this checkout", "MuJoCo C": "this checkout, --physics c"})
# The Hopper's gpu preset with one learner change each (issue 68): the baselines, then the changes.
# One learner change at a time, in sittings of one session each: the preset ("baseline") and
# the changes measured beside it.
LEARNER_CHANGES = [
    {"baseline": [TTS.format(f"Hopper_gpu_v_baseline{n}") for n in ("", "2")],
     **{label: [TTS.format(f"Hopper_gpu_v_{label}")] for label in ("batch32k", "envs4096",
                                                                    "nstep3")}},
    {"baseline": [TTS.format("Hopper_gpu_v_baseline3")],
     **{label: [TTS.format(f"Hopper_gpu_v_{label}")] for label in ("critic_norm",
                                                                    "num_critics2")}},
    {"baseline": [TTS.format("Hopper_gpu_v_obs_norm_base")],
     "obs_norm": [TTS.format("Hopper_gpu_v_obs_norm")]},
]
TRAINERS = {"ours": "our D4PG", "sac": "Brax SAC", "ppo": "Brax PPO", "sb3": "SB3 SAC on PyBullet"}
MARK = "<!-- report.py: {} -->"


def load(name: str) -> dict:
  with open(RESULTS / name) as f:
    return json.load(f)


def num(x, digits: int = 0) -> str:
  return "-" if x is None or x == math.inf else f"{x:,.{digits}f}"


def machine(name: str) -> str:
  """A results file's machine in a few words: "1 H100", "2 H200", "2 Intel cores" (a 2-core
  CPU's maker, and its widest vector unit, where the file names them: "2 AMD cores, AVX2")."""
  text = load(name)["machine"]
  chip = next((c for c in ("H100", "H200") if c in text), None)
  if chip:
    return f"{text.split(' x ')[0]} {chip}"
  if "2-core" in text or text.endswith(" 2 cores"):
    vendor = next((v for v in ("Intel", "AMD") if v in text), None)
    unit = next((u for u in ("AVX-512", "AVX2") if f"({u})" in text), None)
    return (f"2 {vendor} cores" if vendor else "2 CPU cores") + (f", {unit}" if unit else "")
  return text


# How a time-to-score file's seeds were run (its "method"), as a page explains it. Any other
# method is refused: "in turn" (seeds one after another in one process, only the first from
# process start) was kinder than what users get.
METHODS = {
    "fresh, cold": "held-out seeds (100 up), each by `mjx-hopper train` in a fresh process "
                   "from an empty compile cache, timed from process start",
    "fresh, warm": "held-out seeds (100 up), each by `mjx-hopper train` in a fresh process "
                   "from a cache the same settings filled, timed from process start"}


def time_to_score(names: list[str], scale: float = 1.0, tuning: bool = False) -> dict:
  """The seeds of `names`: how many reached the target, and the median, fastest and
  slowest time to it (divided by `scale`: 60 for minutes), a seed that missed counting as
  slowest. Held-out seeds only, unless `tuning` (a change weighed on the tuning seeds 0-9)."""
  figures = [load(n)["figures"] for n in names]
  for name, f in zip(names, figures):
    if f.get("method") not in METHODS:
      raise SystemExit(f"report.py: {name} does not say how its seeds were run: its method is "
                       f"{f.get('method')!r}, not one of {sorted(METHODS)}; run "
                       "benchmarks/time_to_score.py again, which runs each in a fresh process")
    held_out = all(int(seed) >= 100 for seed in f["seeds"])
    if f["method"].startswith("fresh") and not held_out and not tuning:
      raise SystemExit(f"report.py: {name}'s seeds {sorted(map(int, f['seeds']))} are not all "
                       "held out (100 up): the presets were tuned on seeds 0-9")
  runs = [s for f in figures for s in f["seeds"].values()]
  times = [math.inf if s["target_wall_s"] is None else s["target_wall_s"] / scale for s in runs]
  hit = [t for t in times if t < math.inf] or [math.inf]
  steps = [s["target_env_steps"] / 1e6 for s in runs if s["target_env_steps"]]
  return {"target": figures[0]["target"], "agent": figures[0]["agent"].upper(),
          "seeds": len(runs), "reached": sum(t < math.inf for t in times),
          "median": statistics.median(times), "fastest": min(hit), "slowest": max(hit),
          "env_steps": statistics.median(steps) if steps else None,
          "method": "; ".join(sorted({f["method"] for f in figures}))}


MARGIN = 1.5  # a preset's budget over its slowest seed's need (mjx_hopper/settings/presets.py)


def budget(names: list[str]) -> tuple[int, float]:
  """The env steps and minutes a preset trains for: MARGIN times the most that a seed of `names`
  reaching the target needed, rounded up to 0.5M env steps and a whole minute."""
  runs = [s for n in names for s in load(n)["figures"]["seeds"].values() if s["target_wall_s"]]
  steps = MARGIN * max(s["target_env_steps"] for s in runs)
  minutes = MARGIN * max(s["target_wall_s"] for s in runs) / 60
  return int(math.ceil(steps / 500_000) * 500_000), float(math.ceil(minutes))


def score_cells(robot: str) -> list[str]:
  """A robot's score, median time and seeds reaching it: on one GPU (s), then on 2 cores (min)."""
  g, c = time_to_score(GPU[robot]), time_to_score(CPU[robot], 60)
  return [num(g["target"]), num(g["median"]), f"{g['reached']}/{g['seeds']}",
          num(c["target"]), num(c["median"], 1), f"{c['reached']}/{c['seeds']}"]


def env_rates(robot: str) -> dict:
  """PyBullet's (one core), MuJoCo C's (2 threads) and MJX's best env steps/s of one robot, MJX's
  on one device (one core, "mjx1") and on 2."""
  rows = [r for r in load(ENV.get(robot, ENV_OTHERS))["figures"]["rows"] if r["env"] == robot]
  best = lambda engine, devices: max(r["env_steps_per_s"] for r in rows if r["engine"].startswith(
      engine) and r["devices"] in devices)
  return {"pybullet": best("PyBullet", (1,)), "mujoco": best("MuJoCo C", (2,)),
          "mjx1": best("MJX", (1,)), "mjx": best("MJX", (2,))}


def reach(run: dict, score: int) -> float:
  return run[f"to_{score}"]["wall_s"] if run.get(f"to_{score}") else math.inf


def peer_rows() -> list[list]:
  """A row per peers run, with the settings it was given."""
  runs = [(name, run) for name in PEERS for run in load(name)["figures"]["runs"]]
  rows = []
  for name, run in runs:
    rows.append([machine(name), TRAINERS[run["trainer"]], peer_settings(run),
                 f"{run['minutes']:g}", num(reach(run, 1000)),
                 num(reach(run, 2000)), num(run["best_return"]),
                 num(run["env_steps"] / (60 * run["minutes"]))])
  return rows


def peer_settings(run: dict) -> str:
  """What a peers run was given, from its results: our CLI's flags (its seed left out), or the
  settings that the trainer's row in benchmarks/peers.py does not fix."""
  s = run["settings"]
  if run["trainer"] == "ours":
    flags = [w for i, w in enumerate(s) if "--seed" not in s[max(i - 1, 0):i + 1]]
    return f"`{' '.join(flags)}`"
  if run["trainer"] == "sb3":
    clock = ("" if run["meta"].get("clock") == "process start" else
             "; its clock: training only, to 1.5 × the minutes")
    return f"rl-zoo's: gamma {s['gamma']}, learning rate {s['learning_rate']:g}{clock}"
  return f"reward scaling {s['reward_scaling']}, discount {s['discounting']}"


PEER_HEAD = ["machine", "trainer", "settings", "minutes", "to 1,000 (s)", "to 2,000 (s)",
             "best return", "env steps/s"]


def summary() -> str:
  zoo = load(RL_ZOO)["figures"]
  rows = []
  for robot in ROBOTS:
    e, published = env_rates(robot), zoo.get(robot, {})
    rows.append([robot, num(e["mjx1"] / e["pybullet"], 1), num(published.get("sac")),
                 num(published.get("tqc"))])
  return "\n\n".join([
      "Times to score: the sections below. × PyBullet: MJX's env steps/s over PyBullet's, "
      "one core each. rl-zoo: rl-baselines3-zoo's SAC and TQC returns on PyBullet after 1M "
      f"env steps (`{RL_ZOO}`).",
      table(["robot", "× PyBullet", "rl-zoo SAC", "rl-zoo TQC"], rows)])


def time_section(title: str, method: str, runs: dict, unit: str, scale: float, digits: int,
                 explained: set | None = None):
  """A time-to-score section: each task's seeds, in `unit` (seconds over `scale`), and the
  machines and methods of its rows where they differ; its methods explained but for those in
  `explained` (an earlier section's), which it adds to."""
  explained = set() if explained is None else explained
  rows, methods, machines = [], [], []
  for label, names in runs.items():
    t = time_to_score(names, scale)
    steps, minutes = budget(names)
    methods.append(t["method"])
    machines.append(" or ".join(sorted({machine(n) for n in names})))  # each seed on one
    rows.append([label, num(t["target"]), t["agent"], t["seeds"], t["reached"],
                 *(num(t[k], digits) for k in ("median", "fastest", "slowest")),
                 num(t["env_steps"], 2), f"{steps / 1e6:g}", f"{minutes:g}"])
  head = ["task", "score", "agent", "seeds", "reached", f"median ({unit})", f"fastest ({unit})",
          f"slowest ({unit})", "M env steps to it", "budget (M env steps)", "budget (min)"]
  # A column for what differs between the rows: where they ran, how their seeds ran.
  for name, column in (("machine", machines), ("seeds run", methods)):
    if len(set(column)) > 1:
      head.append(name)
      rows = [row + [m] for row, m in zip(rows, column)]
  new = sorted({m for cell in methods for m in cell.split("; ")} - explained)
  explained.update(new)
  if new:
    method += " Seeds run " + "; ".join(f"{m}: {METHODS[m]}" for m in new) + "."
  return (title, method, table(head, rows), [n for v in runs.values() for n in v])


def sections() -> list[tuple[str, str, str, list[str]]]:
  """(title, method, table, results files) of each question after the summary."""
  explained = set()
  out = [time_section("Time to score on one GPU", "Each robot's gpu preset, timed to the score; "
                      f"budget: {MARGIN:g} × the slowest seed's need.", GPU, "s", 1, 0,
                      explained),
         time_section("Time to score on 2 CPU cores", "Each robot's cpu preset (another agent: "
                      "its own with the robot's settings), timed as above.", CPU, "min", 60, 1,
                      explained),
         ("Peers", "Hopper: our D4PG beside Brax's SAC and PPO on our env (each alone on the "
          "GPU) and SB3's SAC on PyBullet (2 cores), each for its minutes, from process start; "
          "16-episode evaluations.",
          table(PEER_HEAD, peer_rows()), list(PEERS))]
  rates = {robot: env_rates(robot) for robot in ROBOTS}
  env_files = sorted({ENV.get(robot, ENV_OTHERS) for robot in ROBOTS})
  cpus = sorted({load(name)["machine"] for name in env_files})
  out.append(("Env throughput on 2 CPU cores", "Auto-resetting envs, random actions: MJX's "
              "best of 64, 256 and 4,096 envs on 1 and 2 XLA devices; MuJoCo C's physics on 2 "
              f"threads; PyBullet on one core. On {' and '.join(cpus)}.",
              table(["robot", "PyBullet", "MJX, 1 core", "MJX, 2 cores", "MuJoCo C, 2 cores",
                     "MJX ÷ MuJoCo C"],
                    [[robot, num(e["pybullet"]), num(e["mjx1"]), num(e["mjx"]),
                      num(e["mujoco"]), num(e["mjx"] / e["mujoco"], 2)]
                     for robot, e in rates.items()]), env_files))
  f32, bf16 = (load(n)["figures"] for n in LEARNER)
  half = {r["robot"]: r["updates_per_s"] for r in bf16["rows"]}
  rows = []
  for r in f32["rows"]:
    dtype = r["overrides"].get("compute_dtype", "float32")
    peak = f32["peaks_bf16_gflops" if dtype == "bfloat16" else "peaks_gflops"]["1"]
    rows.append([r["robot"], num(r["batch"]), dtype, num(r["updates_per_s"]),
                 num(r["gflop_per_update"], 1), num(100 * r["gflops"] / peak, 1),
                 num(half.get(r["robot"]))])
  out.append(("Learner throughput on one GPU", "Each gpu preset's update on random "
              "batches, 100 to a compiled scan; XLA's FLOP count against the measured matmul "
              "peak.",
              table(["robot", "batch", "precision", "updates/s", "GFLOP/update", "% of peak",
                     "bfloat16 updates/s"], rows), list(LEARNER)))
  out.append(learner_changes_section())
  out.append(cpu_learner_section())
  out.append(c_physics_section())
  out.append(warp_section())
  out.append(gymnasium_section())
  out.append(start_section())
  out.append(iteration_section())
  out.append(sweep_section())
  rows = [[machine(name), r["processes"], r["devices"], cache, num(r["first_row_s"], 1),
           num(r["env_steps_per_s"])]
          for name, cache in DISTRIBUTED.items() for r in load(name)["figures"]]
  out.append(("Sweeps over processes", "A 4-seed Hopper sweep (cpu preset) in one process, "
              "then one process per device (`sweep --distributed`); first row from the launch.",
              table(["machine", "processes", "devices", "compile cache", "first row (s)",
                     "env steps/s"], rows),
              list(DISTRIBUTED)))
  out.append(("Population-based training", "HalfCheetah, 16 members (4 learning rates × 4 "
              "noise scales), grid and PBT side by side, a GPU each, 15.6 minutes; PBT steps "
              "every second evaluation.",
              table(["seed", "run", "3,000 first at (s)", "best return", "members' median best",
                     "env steps per member", "env steps/s"], load(PBT)["figures"]["rows"]),
              [PBT]))
  nb = load(NOTEBOOK)["figures"]
  text = table(["section", "minutes"], [[t, num(s / 60, 1)] for t, s in
                                        nb["sections_s"].items() if s >= 30]
               + [["all", num(nb["total_s"] / 60, 1)],
                  ["first video", num(nb["first_video_s"] / 60, 1)]])
  if "runs" in nb:
    text += "\n\n" + table(["run", "stops at", "best evaluation", "score first at (min)"],
                            [[name, num(r["target"]), num(r["best_return"]),
                              num(r["target_wall_s"] and r["target_wall_s"] / 60, 1)]
                             for name, r in nb["runs"].items()])
  jump = time_to_score([NOTEBOOK_JUMP], 60, tuning=True)
  minutes = budget([NOTEBOOK_JUMP])[1]
  text += (f"\n\nThe single high jump's seed (0), its preset in a fresh process: "
           f"{num(jump['target'])} at {num(jump['median'], 1)} min and "
           f"{num(jump['env_steps'], 2)}M env steps; the notebook trains it for {minutes:g} "
           "minutes.")
  installed = ("from a clone in a new venv, its install cell downloading and installing the "
               "project" if nb.get("install", "").startswith("timed") else
               "the project installed")
  out.append(("The notebook on 2 CPU cores", "`notebooks/robolympics.ipynb` in full mode "
              f"from an empty compile cache, {installed} (sections under 30 s left "
              "out); first video from the kernel's start; each run's score on its own clock.",
              text, [NOTEBOOK, NOTEBOOK_JUMP]))
  out.append(pretrained_section(sorted(p.name for p in RESULTS.glob("pretrained_*.json"))))
  rows = []
  for name, job in SUITE.items():
    s = load(name)["figures"]
    rows.append([job, s["tests"] - s["skipped"], s["failed"], num(s["pytest_s"] / 60, 1),
                 num(s["with_setup_s"] / 60, 1), num(s["ledger"]["compiled"]),
                 num(s["ledger"]["compile_s"] / 60, 1)])
  out.append(("Test suite", "CI's jobs in turn, 2 cores, empty cache, in minutes; "
              "compiled: per the ledger. " + compile_flags_line(),
              table(["job", "tests", "failed", "pytest", "with set-up", "compiled",
                     "compiling"], rows) + "\n\n" + suite_files_table(),
              [*SUITE, COMPILE_FLAGS]))
  return out


def suite_files_table() -> str:
  """The heaviest test files of each tier in worker-seconds (their tests' summed seconds; "–":
  not in the tier), and the sum over all files."""
  seconds = {tier: load(name)["figures"]["file_s"] for tier, name in SUITE_FILES.items()}
  names = [name for files in seconds.values()
           for name in sorted(files, key=lambda f: -files[f])[:HEAVIEST_FILES]]
  rows = [[f"`{name}`", *(num(files[name]) if name in files else "–" for files in seconds.values())]
          for name in dict.fromkeys(names)]
  rows.append(["all files", *(num(sum(files.values())) for files in seconds.values())])
  return ("Worker-seconds by test file, the heaviest of each tier:\n\n"
          + table(["file", *seconds], rows))


def compile_flags_line() -> str:
  """The tests' XLA optimisation level weighed, in a sentence: the tiny D4PG chunk's compile
  seconds at level 0 and at level 1 (the suite's before)."""
  data = load(COMPILE_FLAGS)["figures"]
  return (f"The tiny chunk compiles in {num(data['level 0']['chunk_compile_s'], 1)} s at level 0, "
          f"{num(data['level 1']['chunk_compile_s'], 1)} at 1.")


def start_section() -> tuple[str, str, str, list[str]]:
  """A run's start, phase by phase (s from process start), cold and warm, on each machine at
  the code its file measured."""
  columns = {}
  for name in START:
    data = load(name)
    for label, figures in data["figures"]["medians"].items():
      checkout, cache = label.rsplit(", ", 1)
      if checkout == "this checkout":
        columns[f"{machine(name)}, {code(data['commit'])}, {cache}"] = figures
  rows = []
  for label, keys in START_ROWS.items():
    found = [next((c[k] for k in keys if c.get(k) is not None), None) for c in columns.values()]
    rows.append([label, *("–" if x is None else num(x, 0 if keys == ("steps_per_s",) else 1)
                          for x in found)])
  return ("The start, phase by phase", "The main job (Hopper), s from process start, empty "
          "(cold) or warm compile cache; compiles overlap.",
          table(["phase (s)", *columns], rows), list(START))


def fidelity_table() -> str:
  """docs/fidelity.md's table: each robot's episode statistics in PyBullet and in ours, mean ±
  std (statistics 0 in every row left out), with its results file."""
  data = load(FIDELITY)["figures"]
  rows = data["rows"]
  keys = [k for k in rows[0] if k not in ("robot", "policy", "engine")
          and any(r[k] != [0.0, 0.0] for r in rows)]

  def cell(mean: float, std: float) -> str:
    if mean == std == 0:
      return "0"
    digits = next((d for d, top in ((3, 1), (2, 10), (1, 100)) if abs(mean) < top), 0)
    return f"{num(mean, digits)} ± {num(std, digits)}"

  return (f"Episodes under random actions (uniform in [-1, 1]) and zero actions, "
          f"{data['episodes']} per robot, policy and engine; each statistic's mean ± std over "
          "them (reward terms: their mean over an episode's steps).\n\n"
          + table(["robot", "policy", "engine", *keys],
                  [[r["robot"], r["policy"], r["engine"], *(cell(*r[k]) for k in keys)]
                   for r in rows]) + "\n\n" + sources([FIDELITY]))


def sweep_section() -> tuple[str, str, str, list[str]]:
  """Sweeps of S seeds, each S by `mjx-hopper sweep` in a fresh process, timed from launch."""
  rows = []
  for name in SWEEPS:
    found = load(name)["figures"]
    if found.get("method") != SWEPT:
      raise SystemExit(f"report.py: {name} was not timed from the launch of mjx-hopper sweep; "
                       "run benchmarks/sweep_throughput.py again")
    base = min((r for r in found["rows"] if r["members"] == 1), key=lambda r: r["devices"])
    rows += [[machine(name), r["devices"], r["members"], num(r["first_row_s"], 1),
              num(r["env_steps_per_s"]), num(r["env_steps_per_s"] / base["env_steps_per_s"], 2),
              num(r["run_env_steps_per_s"])] for r in found["rows"]]
  return ("Sweeps", "S seeds of D4PG on Hopper in one program by `mjx-hopper sweep`, a fresh "
          "process per S, empty cache, from launch: env steps/s after the first row and over the "
          "whole run; × one run: over S = 1.",
          table(["machine", "devices", "members", "first row (s)", "env steps/s", "× one run",
                 "whole run: env steps/s"], rows), list(SWEEPS))


def iteration_section() -> tuple[str, str, str, list[str]]:
  """Where a training run's time goes, on 2 CPU cores (with each choice of matrix kernels) and
  on one GPU: its run, and a chunk's parts."""
  data = {label: load(name)["figures"] for label, name in ITERATION.items()}
  parts = {label: d["parts"] for label, d in data.items()}
  rows = [[name, *(num(p[key]) for p in parts.values())]
          for name, key in (("env steps", "env_steps_per_chunk"),
                            ("updates", "updates_per_chunk"))]
  rows += [[name, *(num(p[key], 3) for p in parts.values())]
           for name, key in (("physics (s)", "physics_s"),
                             ("episode starts' refill (s)", "refill_s"),
                             ("acting and replay insert (s)", "acting_and_insert_s"),
                             ("learner, replay samples in it (s)", "learner_s"),
                             ("whole chunk (s)", "chunk_s"))]
  rows += [[name, *(f"{p[key] / p['chunk_s']:.0%}" for p in parts.values())]
           for name, key in (("physics's share", "physics_s"), ("learner's share", "learner_s"))]
  rows += [[name, *(num(d["run"][key], digits) for d in data.values())]
           for name, key, digits in (("run: chunks' env steps/s", "chunk_env_steps_per_s", 0),
                                     ("run: wall clock's env steps/s", "wall_env_steps_per_s", 0))]
  rows.append(["run: pauses after the first row (evaluations, logs, saves)",
               *(f"{d['run']['pause_share']:.1%}" for d in data.values())])
  return ("Where a chunk's time goes", "A preset's training run (cold cache) and a chunk's "
          "parts, each timed alone: the Hopper's cpu preset on 2 CPU cores with XLA's matrix "
          "kernels (setup's) and YNNPACK's; the Hopper's and the Humanoid's gpu presets on one "
          "GPU.", table(["a chunk's", *data], rows), list(ITERATION.values()))


def pretrained_section(names: list[str]) -> tuple[str, str, str, list[str]]:
  """The shipped policies (mjx_hopper/faces/pretrained/): how each was trained, and its file's
  return."""
  rows = []
  for name in names:
    r = load(name)["figures"]
    rows.append([r["robot"], num(r["target"]), r["seed"], num(r["env_steps"] / 1e6, 2),
                 num(r["wall_s"]), num(r["best_eval_return"]),
                 f"{num(r['return'])} ± {num(r['return_std'])}", num(r["file_bytes"] / 1024)])
  return ("Pretrained policies", "`mjx_hopper/faces/pretrained/`: each robot's gpu preset "
          "trained past its score, the best policy exported, the file evaluated.",
          table(["robot", "score", "seed", "env steps (M)", "training (s)", "best evaluation",
                 "the file's return", "file (KiB)"], rows), names)


def changes_table(sittings: list[dict]) -> tuple[str, list[str], dict]:
  """A preset against itself with one change at a time, in `sittings` (each a baseline and
  the changes measured beside it); the table, its files, and the last baseline's figures."""
  rows, names = [], []
  for sitting in sittings:
    base = time_to_score(sitting["baseline"], tuning=True)
    commit = load(sitting["baseline"][0])["commit"].split("+")[0]
    for label, files in sitting.items():
      t = time_to_score(files, tuning=True)
      change = re.findall(r"--(?:train-)?set (\S+)", load(files[0])["command"])
      rows.append([", ".join(change) or f"none (the preset at {commit})", t["seeds"],
                   t["reached"], num(t["median"], 1), num(t["env_steps"], 2),
                   num(t["median"] / base["median"], 2)])
      names += files
  return (table(["change", "seeds", "reached", "median (s)", "env steps (M)", "× preset"], rows),
          names, base)


def learner_changes_section() -> tuple[str, str, str, list[str]]:
  """The Hopper's gpu preset against itself with one learner change at a time."""
  text, names, base = changes_table(LEARNER_CHANGES)
  return ("One learner change at a time on one GPU",
          f"The Hopper's gpu preset to 2,500, one change each, seeds run {base['method']} "
          "(their lines say which; 0-9 tune); × preset: over the median of the preset above "
          "it, in the same session.", text, names)


def cpu_learner_section() -> tuple[str, str, str, list[str]]:
  """The Hopper's cpu preset's learner at other batch sizes, then a change to it timed to the
  score beside the preset."""
  found = load(LEARNER_CPU)["figures"]
  peak = found["peaks_gflops"]["2"]
  rows = [[num(r["batch"]), num(r["updates_per_s"]), num(r["updates_per_s"] * r["batch"]),
           num(r["gflop_per_update"], 2), num(100 * r["gflops"] / peak, 1)]
          for r in found["rows"]]
  critics = {change: load(name)["figures"] for change, name in LEARNER_CPU_CRITICS.items()}
  preset = critics["none"]["rows"][0]["updates_per_s"]
  critic_rows = [[change, num(r["updates_per_s"]), num(r["updates_per_s"] / preset, 2),
                  num(r["gflop_per_update"], 2),
                  num(100 * r["gflops"] / figures["peaks_gflops"]["2"], 1)]
                 for change, figures in critics.items() for r in figures["rows"]]
  text, names, base = changes_table(LEARNER_CHANGES_CPU)
  return ("The learner on 2 CPU cores",
          "The Hopper's cpu preset's update on random batches, 100 to a compiled scan, 2 XLA "
          "devices; XLA's FLOP count against the measured matmul peak: at other batch sizes, "
          "then with a cheaper critic (× preset: in the same session). Below them, the preset "
          f"to 2,000 with one change, seeds run {base['method']} (their lines say which).",
          table(["batch", "updates/s", "samples/s", "GFLOP/update", "% of peak"], rows)
          + "\n\n" + table(["critic change", "updates/s", "× preset", "GFLOP/update",
                             "% of peak"], critic_rows)
          + "\n\n" + text, [LEARNER_CPU, *LEARNER_CPU_CRITICS.values(), *names])


def c_physics_section() -> tuple[str, str, str, list[str]]:
  """The Hopper's env step with its physics in MJX against MuJoCo C's (compile and speed), then
  each engine's time to score and the Hopper's first training row."""
  found = load(C_PHYSICS)["figures"]
  by = {(r["engine"], r["batch"]): r for r in found["rows"]}
  rows = []
  for batch in sorted({b for e, b in by if e == "MJX"}):
    mjx, c = by[("MJX", batch)], by[("C", batch)]
    rows.append([num(batch), num(mjx["compile_s"], 1), num(c["compile_s"], 1),
                 num(c["compile_s"] / mjx["compile_s"], 2), num(mjx["env_steps_per_s"]),
                 num(c["env_steps_per_s"]), num(c["env_steps_per_s"] / mjx["env_steps_per_s"], 2)])
  checks = found["agreement"]
  passed = all(checks[k][f"{t}_pass"] for k in ("oracle_MJX", "oracle_C")
               for t in ("random_states", "one_step", "episode_statistics"))
  start_file, start_labels = PHYSICS_START
  starts = load(start_file)["figures"]["medians"]
  first = {engine: [starts[f"{label}, {cache}"]["first_train"] for cache in ("cold", "warm")]
           for engine, label in start_labels.items()}
  trained = []
  for robot, engines in PHYSICS_TTS.items():
    runs = {engine: time_to_score([name], 60) for engine, name in engines.items()}
    for engine, t in runs.items():
      start = [num(x, 1) for x in first[engine]] if robot == "Hopper" else ["-", "-"]
      trained.append([robot, engine, f"{t['reached']}/{t['seeds']}", num(t["median"], 1),
                      num(t["env_steps"], 2), *start])
    ratios = ([num(c / m, 2) for c, m in zip(first["MuJoCo C"], first["MJX"])]
              if robot == "Hopper" else ["", ""])
    trained.append([robot, "C ÷ MJX", "", num(runs["MuJoCo C"]["median"]
                                              / runs["MJX"]["median"], 2), "", *ratios])
  return ("MuJoCo C physics on 2 CPU cores",
          "The Hopper's env step in MJX or MuJoCo C (`--physics c`), random actions, 2 XLA "
          "devices. Both " + ("pass" if passed else "do not all pass") + " the PyBullet checks.",
          table(["envs", "MJX compile (s)", "C compile (s)", "C ÷ MJX", "MJX env steps/s",
                 "C env steps/s", "C ÷ MJX"], rows)
          + "\n\nTo the cpu score, seeds fresh, cold; first training row from process start, "
          "in turns:\n\n"
          + table(["robot", "physics", "reached", "median (min)", "M env steps",
                   "first row, cold (s)", "warm (s)"], trained),
          [C_PHYSICS, *(n for e in PHYSICS_TTS.values() for n in e.values()), start_file])


def warp_section() -> tuple[str, str, str, list[str]]:
  """MJX's two physics implementations on each robot: the first call, physics steps/s, and the
  distance to MuJoCo C with the models' solver settings and with a converged solver."""
  found = load(WARP)["figures"]
  rows = [[r["robot"], r["impl"], num(r["first_call_s"], 1), num(r["physics_steps_per_s"]),
           num(r["qpos_gap_last"], 2), num(r["qpos_gap_last_converged"], 3)]
          for r in found["rows"] if "error" not in r]
  return ("MJX's JAX and Warp physics on one GPU",
          f"Each robot's model, {num(found['worlds'])} worlds, {found['steps']} physics steps "
          f"from random velocities; largest qpos distance to MuJoCo C ({found['reference_worlds']}"
          " worlds) with the models' solvers and converged. Warp's first call builds its kernels.",
          table(["robot", "physics", "first call (s)", "physics steps/s", "to C",
                 "to C, converged"], rows), [WARP])


def gymnasium_section() -> tuple[str, str, str, list[str]]:
  """The Gymnasium door's env steps/s against the JAX env's."""
  figures = load(GYMNASIUM)["figures"]
  jax_rate = figures["rows"][0]["env_steps_per_s"]
  rows = [[r["engine"], num(r["num_envs"]), num(r["env_steps_per_s"]),
           num(r["env_steps_per_s"] / jax_rate, 2)] for r in figures["rows"]]
  return ("The Gymnasium door on 2 CPU cores", "Hopper, random actions, through "
          "`envs.to_gymnasium` (NumPy in and out, a jit step per call) against the JAX env's "
          "compiled scan, in turns in one process.",
          table(["engine", "envs", "env steps/s", "× JAX env"], rows), [GYMNASIUM])


def code(commit: str) -> str:
  """A results file's code commit, its hash cut to 7 digits; an older file that does not know it
  says where its figures were filed ("unknown; results committed in C": "in C")."""
  text = commit.removeprefix("unknown; ")
  if text != commit:
    return text.replace("results committed in", "in")
  return re.sub(r"\b([0-9a-f]{7})[0-9a-f]+", r"\1", commit)


def benchmarks_page() -> str:
  parts = ["# Benchmarks", "Made by `python benchmarks/report.py` from the "
           "`benchmarks/results/` files under each table (date, machine, code, command in "
           "benchmarks/); do not edit. Machines are noisy: compare rows of one run.",
           "## Summary", summary()]
  for title, method, text, names in sections():
    parts += [f"## {title}", method, text, sources(names)]
  return "\n\n".join(parts) + "\n"


def sources(names: list[str]) -> str:
  """The lines naming the results files `names` under a table: files made on one machine, day
  and commit by one command share a line, and so do those whose command is it with arguments
  added (each file says its own). A command's --out (where it left its episodes) and --label
  (in its file's name) are left out."""
  made = {}
  for n in dict.fromkeys(names):
    r = load(n)
    command = re.sub(r" --(out|label) \S+", "", r["command"])
    command = re.sub(r"^python \S*?benchmarks/", "", command)
    command = command.replace('bash benchmarks/gpu.sh "python benchmarks/', 'gpu.sh "')
    made.setdefault((r["date"], machine(n), code(r["commit"]), command), []).append(n)
  lines = {}
  for (date, where, commit, command), files in made.items():
    base = next((k for k in lines if k[:3] == (date, where, commit)
                 and command.startswith(k[3] + " ")), None)
    listed = [f"`{n.removesuffix('.json')}`" for n in files]
    if base is None:
      lines[(date, where, commit, command)] = listed
    else:
      lines[base] += [f"{name} + `{command[len(base[3]) + 1:]}`" for name in listed]
  return "\n".join(f"- {', '.join(listed)} ({date}, {where}, {commit}): `{command}`"
                   for (date, where, commit, command), listed in lines.items())


def readme_table() -> str:
  rows = [[f'<img src="{media()}/{robot}.gif" width="160">', robot, *score_cells(robot)]
          for robot in ROBOTS]
  gpus = " or ".join(sorted({machine(name) for robot in ROBOTS for name in GPU[robot]}))
  return table(["", "robot", "score (GPU)", f"median on {gpus} (s)",
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
          "training cell stops at its score, or at its time budget.")


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
  fidelity = ROOT / "docs" / "fidelity.md"
  return {ROOT / "BENCHMARKS.md": benchmarks_page(),
          readme: splice(readme.read_text(), "results", readme_table()),
          fidelity: splice(fidelity.read_text(), "fidelity", fidelity_table()),
          notebook_path: json.dumps(notebook, indent=1, ensure_ascii=False) + "\n"}


def used_files() -> set[str]:
  """Every results file the pages are made from."""
  return {n for *_, names in sections() for n in names} | {RL_ZOO, FIDELITY}


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
