"""The results pages and their data: benchmarks/report.py's pages are up to date, every results
file a page names exists, and every results file is used. Reads files only: no JAX."""

import json
import pathlib
import re
import subprocess
import sys

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
  seeds = {str(i): {"target_wall_s": t, "target_env_steps": None if t is None else 10**6}
           for i, t in enumerate([30.0, None, 10.0, 20.0])}
  (tmp_path / "a.json").write_text(json.dumps(
      {"figures": {"target": 2500.0, "agent": "d4pg", "seeds": seeds}}))
  monkeypatch.setattr(report, "RESULTS", tmp_path)
  t = report.time_to_score(["a.json"])
  assert (t["seeds"], t["reached"], t["median"], t["fastest"], t["slowest"]) == (4, 3, 25.0,
                                                                                 10.0, 30.0)

