"""The test suite's wall clock as CI runs it: `bash scripts/test.sh` (the quick tier on Python
3.12, the newest releases; with --slow, `scripts/test.sh -m slow`, the slow tier), or with
--floor `bash .ci/floor` (Python 3.11, the oldest releases, the tests that lean on each
dependency's API), from an empty compile cache, with the outcome, each test file's seconds and
the compile ledger's totals (tests/ledger.py).

    python benchmarks/suite_time.py --label quick --cache /tmp/suite_cache
    python benchmarks/suite_time.py --slow --label slow --cache /tmp/suite_cache
    python benchmarks/suite_time.py --floor --label floor_py311

Writes benchmarks/results/suite_time_LABEL.json. Run it on an otherwise idle machine: the suite
is two test workers, one per core of CI's two. As CI does, give the quick tier an empty --cache
and the slow tier the same one after it.
"""

from __future__ import annotations

import collections
import os
import re
import subprocess
import tempfile
import time
import xml.etree.ElementTree as ET

import common

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")


def figures(output: str, junit: str, wall_s: float) -> dict:
  """The outcome counts, pytest's seconds and each file's summed test seconds (longest first),
  from the command's output and pytest's JUnit XML."""
  suite = ET.parse(junit).getroot()
  suite = suite if suite.tag == "testsuite" else suite.find("testsuite")
  per_file = collections.Counter()
  for case in suite.iter("testcase"):
    per_file[case.get("classname").split(".")[-1] + ".py"] += float(case.get("time"))
  versions = re.search(r"Python (\S+), jax (\S+)", output)
  ledger = re.search(r"all test files: (\d+) programs, (\d+) compiled and (\d+) from the cache, "
                     r"(\d+) s compiling, (\d+) s tracing, (\d+) s lowering, (\d+) trainer "
                     r"configurations", output)
  return {"python": versions and versions.group(1), "jax": versions and versions.group(2),
          "tests": int(suite.get("tests")), "failed": int(suite.get("failures")) + int(
              suite.get("errors")), "skipped": int(suite.get("skipped")),
          "pytest_s": round(float(suite.get("time"))), "with_setup_s": round(wall_s),
          "file_s": {name: round(s, 1) for name, s in per_file.most_common()},
          "ledger": ledger and dict(zip(("programs", "compiled", "cache_hits", "compile_s",
                                         "trace_s", "lower_s", "trainer_configurations"),
                                        map(int, ledger.groups())))}


def main() -> None:
  p = common.parser(__doc__)
  p.add_argument("--floor", action="store_true", help="the floor job (.ci/floor)")
  p.add_argument("--slow", action="store_true", help="the slow tier (scripts/test.sh -m slow)")
  p.add_argument("--cache", help="the compile cache's folder, as CI's slow tier finds the quick "
                 "tier's (default: a new empty one)")
  p.add_argument("--label", default="py312")
  args = p.parse_args()
  script = [".ci/floor"] if args.floor else ["scripts/test.sh", *(["-m", "slow"] if args.slow
                                                                  else [])]
  with tempfile.TemporaryDirectory() as scratch:
    junit = os.path.join(scratch, "junit.xml")
    start = time.perf_counter()
    done = subprocess.run(["bash", *script, f"--junitxml={junit}"], cwd=ROOT, text=True,
                          env=dict(os.environ, MJX_HOPPER_JAX_CACHE=args.cache or os.path.join(
                              scratch, "jax")),
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    wall = time.perf_counter() - start
    print(done.stdout[-3000:])
    common.write_results(f"suite_time_{args.label}", figures(done.stdout, junit, wall))


if __name__ == "__main__":
  main()
