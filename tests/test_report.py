"""The results pages and their data: benchmarks/report.py's pages are up to date, every results
file a page names exists, and every results file is used. Reads files only: no JAX."""

import json
import pathlib
import re
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
sys.path.insert(0, str(ROOT / "benchmarks"))
import report  # noqa: E402

FIELDS = {"command", "machine", "date", "commit", "figures"}


def test_the_pages_are_what_the_results_make():
  done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "report.py"), "--check"],
                        capture_output=True, text=True)
  assert done.returncode == 0, done.stdout + done.stderr


def test_every_results_file_is_used_and_every_named_one_exists():
  present = {p.name for p in RESULTS.iterdir()}
  assert report.used_files() == present
  page = "\n".join((ROOT / name).read_text() for name in ("BENCHMARKS.md", "docs/fidelity.md"))
  # A table's source lines name its files without ".json": "- `name`, `name` (date, ...): ..."
  sources = {f"{name}.json" for line in page.splitlines() if line.startswith("- `")
             for name in re.findall(r"`([\w.\-]+)`", line.split(" (", 1)[0])}
  assert sources | set(re.findall(r"`([\w.\-]+\.json)`", page)) == present


def test_every_results_file_records_how_it_was_made():
  for path in sorted(RESULTS.iterdir()):
    record = json.loads(path.read_text())
    assert FIELDS <= set(record), path.name
    assert re.fullmatch(r"\d{4}-\d{2}-\d{2}", record["date"]), path.name
    assert all(record[k] for k in ("command", "machine", "commit")), path.name


def test_time_to_score_is_the_median_over_seeds_with_misses_slowest(tmp_path, monkeypatch):
  seeds = {str(100 + i): {"target_wall_s": t, "target_env_steps": None if t is None else 10**6}
           for i, t in enumerate([30.0, None, 10.0, 20.0])}
  figures = {"method": "fresh, cold", "target": 2500.0, "agent": "d4pg", "seeds": seeds}
  (tmp_path / "a.json").write_text(json.dumps({"figures": figures}))
  monkeypatch.setattr(report, "RESULTS", tmp_path)
  t = report.time_to_score(["a.json"])
  assert (t["seeds"], t["reached"], t["median"], t["fastest"], t["slowest"]) == (4, 3, 25.0,
                                                                                 10.0, 30.0)
  assert t["method"] == "fresh, cold"


def test_a_time_to_score_file_of_fresh_processes_holds_held_out_seeds(tmp_path, monkeypatch):
  figures = {"method": "fresh, warm", "target": 2500.0, "agent": "d4pg",
             "seeds": {"100": {"target_wall_s": 1.0, "target_env_steps": 1},
                       "3": {"target_wall_s": 1.0, "target_env_steps": 1}}}
  (tmp_path / "c.json").write_text(json.dumps({"figures": figures}))
  monkeypatch.setattr(report, "RESULTS", tmp_path)
  with pytest.raises(SystemExit, match=r"c.json's seeds \[3, 100\] are not all held out"):
    report.time_to_score(["c.json"])
  assert report.time_to_score(["c.json"], tuning=True)["seeds"] == 2  # a change weighed


def test_a_resumed_runs_time_to_its_score_counts_the_part_before_it():
  import notebook_time
  walls = [10.0, 20.0, 5.0, 15.0, 3.0]  # two resumes: the clock starts again twice
  evals = [{"wall_s": w, "env_steps": i} for i, w in enumerate(walls)]
  assert [e["wall_s"] for e in notebook_time.one_clock(evals)] == [10.0, 20.0, 25.0, 35.0, 38.0]


# "in turn": seeds one after another in one process, only the first from process start.
@pytest.mark.parametrize("method", [None, "seeds in turn", "in turn"])
def test_a_time_to_score_file_that_does_not_say_how_its_seeds_ran_is_refused(
    tmp_path, monkeypatch, method):
  figures = {"target": 2500.0, "agent": "d4pg", "seeds": {}, "method": method}
  (tmp_path / "b.json").write_text(json.dumps({"figures": {
      k: v for k, v in figures.items() if v is not None}}))
  monkeypatch.setattr(report, "RESULTS", tmp_path)
  with pytest.raises(SystemExit, match=rf"b.json does not say how its seeds were run: its "
                     rf"method is {method!r}, not one of"):
    report.time_to_score(["b.json"])


def write_one_seed(path, machine: str, method: str) -> None:
  """A time-to-score results file of seed 100, which reached 2,500 at 30 s, on `machine`."""
  seeds = {"100": {"target_wall_s": 30.0, "target_env_steps": 10**6}}
  path.write_text(json.dumps({"machine": machine, "figures": {
      "method": method, "target": 2500.0, "agent": "d4pg", "seeds": seeds}}))


def test_a_time_section_names_each_rows_method_where_they_differ(tmp_path, monkeypatch):
  for name, method in (("a.json", "fresh, cold"), ("b.json", "fresh, warm")):
    write_one_seed(tmp_path / name, "AMD EPYC (AVX2), 2 cores", method)
  monkeypatch.setattr(report, "RESULTS", tmp_path)
  _, text, rows, _ = report.time_section("t", "Timed.", {"A": ["a.json"], "B": ["b.json"]},
                                         "s", 1, 0)
  assert rows.splitlines()[0].endswith("| seeds run |")
  assert rows.splitlines()[2].endswith("| fresh, cold |")
  assert rows.splitlines()[3].endswith("| fresh, warm |")
  assert text.startswith("Timed. Seeds run fresh, cold: held-out seeds (100 up), each by "
                         "`mjx-hopper train` in a fresh process")
  assert "; fresh, warm: held-out seeds (100 up), each by `mjx-hopper train` in a fresh " \
         "process from a cache the same settings filled" in text
  _, _, rows, _ = report.time_section("t", "Timed.", {"A": ["a.json", "b.json"]}, "s", 1, 0)
  assert "| 2 | 2 |" in rows  # a row of two files' seeds, one each way, explained
  _, text, rows, _ = report.time_section("t", "Timed.", {"A": ["a.json"]}, "s", 1, 0)
  assert "seeds run" not in rows and "fresh, cold:" in text
  assert "machine" not in rows  # the rows' machines are the same


def test_a_time_section_names_each_rows_machine_where_they_differ(tmp_path, monkeypatch):
  for name, cpu in (("a.json", "Intel(R) Xeon(R) Processor, 2 cores"),
                    ("b.json", "AMD EPYC (AVX2), 2 cores")):
    write_one_seed(tmp_path / name, cpu, "fresh, cold")
  monkeypatch.setattr(report, "RESULTS", tmp_path)
  _, _, rows, _ = report.time_section("t", "Timed.", {"A": ["a.json"], "B": ["b.json"]},
                                      "s", 1, 0)
  assert rows.splitlines()[0].endswith("| machine |")
  assert rows.splitlines()[2].endswith("| 2 Intel cores |")
  assert rows.splitlines()[3].endswith("| 2 AMD cores, AVX2 |")

