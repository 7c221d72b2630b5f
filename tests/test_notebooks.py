"""The Robolympics notebook runs top to bottom in its short mode (MJX_HOPPER_SHORT=1: tiny
budgets, nothing installed, no network), and every step of its workflow leaves its mark."""

import json
import pathlib
import subprocess
import sys

import nbformat
import pytest
from nbclient import NotebookClient

# The notebook runs once, in the module's fixture, within its first test's time limit: the
# whole notebook, not one test, so it has a limit of its own.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(1500)]
NOTEBOOK = pathlib.Path(__file__).parent.parent / "notebooks" / "robolympics.ipynb"

# The hash of the text of a DDPG run's training chunk, as `trainers.build` traces it: in the
# notebook's kernel after all its cells, and in a fresh process.
CHUNK_TEXT = """
import hashlib
import jax
from mjx_hopper.run import trainers
from mjx_hopper.settings.plan import resolve


def chunk_text(cfg):
  plan = resolve(cfg, 1)
  trainer = trainers.build(plan)
  state = jax.eval_shape(lambda: trainers.init(plan, trainer, [{"seed": 0}], begin=False))
  return hashlib.sha256(trainer.chunk.lower(state).as_text(debug_info=False).encode()).hexdigest()
"""
# Run in the notebook's kernel after its own cells: what its workflow left behind.
FACTS = CHUNK_TEXT + """
import json
print("FACTS " + json.dumps({
    "ddpg_chunk": chunk_text(ddpg),
    "commands": [" ".join(c) for c in commands],
    "high_jump_terms": sorted(jumps),
    "d4pg_log": {kind: columns["env_steps"].tolist()
                 for kind, columns in notebook.read_log(f"{cfg.out_dir}/log.csv").items()},
    "checkpoints": sorted(int(s) for s in os.listdir(f"{cfg.out_dir}/checkpoints") if s.isdigit()),
    "rewards": list(episodes["rewards"].shape),
    "evaluations": {c.out_dir: len(notebook.read_log(f"{c.out_dir}/log.csv")["eval"]["env_steps"])
                    for c in (ddpg, dmpo, walker, jump_cfg, ant_cfg)},
    "tasks": [json.load(open(f"{c.out_dir}/config.json"))["env"] for c in (cfg, jump_cfg, ant_cfg)],
    "jump_settings": json.load(open(f"{jump_cfg.out_dir}/config.json"))["env_settings"],
    "jump_terms": sorted(k for k in jump_episodes
                         if k not in ("return", "length", "rewards", "qpos")),
    "videos": sorted(p for p in os.listdir() if p.endswith(".mp4")),
    "pbt": json.load(open(f"{pbt_cfg.out_dir}/config.json"))["pbt"],
    "pbt_members": sorted(set(notebook.read_log(f"{pbt_cfg.out_dir}/log.csv")["eval"]["member"])),
}))
"""


@pytest.fixture(scope="module")
def executed(tmp_path_factory):
  """The notebook's cells with their outputs, and its FACTS, after a run in a scratch folder
  (so that its runs and videos do not land in the repository)."""
  notebook = nbformat.read(NOTEBOOK, as_version=4)
  notebook.cells.append(nbformat.v4.new_code_cell(FACTS))
  folder = tmp_path_factory.mktemp("robolympics")
  with pytest.MonkeyPatch.context() as patch:
    patch.setenv("MJX_HOPPER_SHORT", "1")  # the kernel also inherits conftest's XLA_FLAGS
    NotebookClient(notebook, timeout=600, kernel_name="python3",
                   resources={"metadata": {"path": str(folder)}}).execute()
  facts = json.loads(notebook.cells[-1].outputs[0]["text"].removeprefix("FACTS "))
  return notebook.cells[:-1], facts


def outputs(cells, kind=None):
  return [o for c in cells if c.cell_type == "code" for o in c.outputs
          if kind is None or o["output_type"] == kind]


def text(cells) -> str:
  return "".join(o.get("text", "") for o in outputs(cells, "stream"))


def test_runs_without_errors_and_installs_nothing(executed):
  cells, facts = executed
  assert not outputs(cells, "error")
  assert not any("pip" in c for c in facts["commands"])  # the checkout's package is in place
  assert "to install:" in text(cells)


def test_custom_task_has_its_own_reward_terms(executed):
  _, facts = executed
  assert "height" in facts["high_jump_terms"] and "progress" not in facts["high_jump_terms"]


def test_trains_checkpoints_and_resumes_from_the_saved_step(executed):
  cells, facts = executed
  log = facts["d4pg_log"]
  assert log["eval"] == [40, 80, 120, 160]         # 80 env steps, then 80 more after resuming
  assert max(log["train"]) == 160
  assert facts["checkpoints"] == [10, 20]          # iterations of 8 env steps
  assert "resumed from" in text(cells) and "step 10" in text(cells)
  assert all(count == 2 for count in facts["evaluations"].values())  # and the events


def test_trains_section_2s_classes_and_records_them(executed):
  _, facts = executed
  assert facts["tasks"] == ["__main__:Hopper", "__main__:HighJump", "__main__:AntLongJump"]
  assert facts["jump_settings"] == {"height_weight": 10.0}
  assert "height" in facts["jump_terms"] and "progress" not in facts["jump_terms"]


def test_shows_frames_plots_videos_and_totals(executed):
  cells, facts = executed
  images = [o for o in outputs(cells) if "image/png" in o.get("data", {})]
  assert len(images) >= 9  # a frame, two reward plots, five learning curves, PBT's lineage
  html = [o.get("data", {}).get("text/html", "") for o in outputs(cells)]
  # A pretrained policy; random actions; trained beside random, for the Hopper and the high
  # jump; the PBT jump's best member; the Ant's long jump; Walker2D.
  assert [h.count("<video") for h in html if "<video" in h] == [1, 1, 2, 2, 1, 1, 1]
  assert facts["videos"] == ["ant_long_jump.mp4", "high_jump_d4pg.mp4", "high_jump_pbt.mp4",
                             "high_jump_random.mp4", "hopper_d4pg.mp4", "hopper_random.mp4",
                             "pretrained.mp4", "walker2d_d4pg.mp4"]
  assert facts["rewards"] == [5, 30]
  assert text(cells).count("Total reward in episode") == 5


def test_section_7_trains_a_population(executed):
  cells, facts = executed
  assert facts["pbt"] == {"every": 2, "fraction": 0.25, "factors": [0.8, 1.25], "bounds": {}}
  assert facts["pbt_members"] == [0, 1, 2, 3]
  assert "ranking by the best evaluation:" in text(cells) and "| copied from |" in text(cells)


def test_a_run_after_its_cells_is_traced_as_in_a_fresh_process(executed):
  # So that a run after other work in the kernel (the notebook's DDPG after its PBT cell) loads
  # its programs from the compile cache: JAX's in-memory caches, once full, changed how it was
  # traced (trainers.build empties them).
  _, facts = executed
  fresh = subprocess.run(
      [sys.executable, "-c", CHUNK_TEXT + "import sys\nsys.path.insert(0, 'tests')\n"
       "import configs\nprint(chunk_text(configs.tiny('ddpg')))"],
      capture_output=True, text=True, check=True, cwd=NOTEBOOK.parent.parent)
  assert facts["ddpg_chunk"] == fresh.stdout.split()[-1]
