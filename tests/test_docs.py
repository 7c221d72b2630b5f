"""The pages say what is true: every shell command in README.md and docs/*.md names a command,
subcommand, flag and extra that exist (read from each program's --help and from pyproject),
and the Brax page's code runs as written, in order."""

import contextlib
import glob
import io
import os
import re
import shlex
import subprocess
import sys
import textwrap
import tomllib

import jax
import numpy as np
import pytest

from mjx_hopper import envs
from mjx_hopper.faces import cli

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
PAGES = ["README.md"] + sorted(os.path.relpath(p, ROOT)
                               for p in glob.glob(os.path.join(ROOT, "docs", "*.md")))
# The programs the pages may name: a command whose first word is another fails, to be added here.
PROGRAMS = ("mjx-hopper", ".venv/bin/mjx-hopper", "bash", "python", "pip", ".venv/bin/pip",
            "cd", "git", "srun", "mpirun", "time")
FLAG = re.compile(r"(?<![\w-])--[a-z0-9][\w-]*")


def commands(page: str) -> list[list[str]]:
  """The page's shell commands as words: each line of its bash blocks (with its continuations)
  and each inline code span that starts with one of PROGRAMS, split at && and ;."""
  with open(os.path.join(ROOT, page)) as f:
    text = f.read()
  lines = [line for block in re.findall(r"```(?:bash|sh)\n(.*?)```", text, re.S)
           for line in block.replace("\\\n", " ").splitlines()]
  spans = [s for s in re.findall(r"(?<!`)`([^`\n]+)`(?!`)", text)
           if s.split(" ")[0] in PROGRAMS[:2] or re.match(r"(bash|python|\.venv/bin/pip|pip) ", s)]
  out = []
  for line in lines + spans:
    words = shlex.split(line, comments=True)
    while words:
      cut = next((i for i, w in enumerate(words) if w in ("&&", ";")), len(words))
      out.append(words[:cut])
      words = words[cut + 1:]
  return [w for w in out if w]


def help_flags(argv: list[str]) -> set[str]:
  """The flags that `mjx-hopper ARGV --help` lists as its options (with ARGV empty, the global
  ones of its usage line): not the examples of its description."""
  return option_flags(cli_help(argv), usage=not argv)


def option_flags(text: str, usage: bool = False) -> set[str]:
  """The flags of a --help text's option lines (an indented flag, then its help two spaces
  on), or of its usage, up to the first blank line."""
  if usage:
    return set(FLAG.findall(text.split("\n\n")[0]))
  return {f for line in text.splitlines() if re.match(r"\s+-", line)
          for f in FLAG.findall(re.split(r"\s{2,}", line.strip())[0])}


def cli_help(argv: list[str]) -> str:
  """What `mjx-hopper ARGV --help` prints; it must succeed."""
  text = io.StringIO()
  try:
    with contextlib.redirect_stdout(text):
      cli.main([*argv, "--help"])
  except SystemExit as done:
    assert done.code in (0, None), f"mjx-hopper {' '.join(argv)} --help failed"
  return text.getvalue()


def script_flags(script: str) -> set[str]:
  done = subprocess.run([sys.executable, os.path.join(ROOT, script), "--help"], cwd=ROOT,
                        capture_output=True, text=True)
  assert done.returncode == 0, f"python {script} --help failed: {done.stderr[-500:]}"
  return option_flags(done.stdout)


def extras() -> set[str]:
  with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
    return set(tomllib.load(f)["project"]["optional-dependencies"])


def problems(words: list[str], top: set[str]) -> list[str]:
  """What is wrong with one command, [] if nothing."""
  while words and (re.match(r"^[A-Z_]+=", words[0]) or words[0] in ("time", "srun", "mpirun")):
    words = words[1:] if words[0] not in ("srun", "mpirun") else words[next(
        i for i, w in enumerate(words) if w.endswith("mjx-hopper")):]
  program, args = words[0], words[1:]
  used = {a.split("=")[0] for a in args if a.startswith("--")}
  if program.endswith("mjx-hopper"):
    if not args or args[0].startswith("-"):
      return sorted(used - top)
    if re.fullmatch(r"[A-Z]+:?", args[0]):  # a placeholder (or a message's "COMMAND:")
      return []
    if args[0] not in subcommands():
      return [f"no subcommand {args[0]!r}"]
    return sorted(used - help_flags([args[0]]) - top)
  if program == "bash" and args[0] == "scripts/main.sh":
    return sorted({a.split("=")[0] for a in args[1:] if a.startswith("--")}
                  - help_flags(["train"]) - top)
  if program == "bash" and args[0] in ("scripts/test.sh", "scripts/setup.sh"):
    given = args[1] if args[0] == "scripts/setup.sh" and len(args) > 1 else None
    return [] if given is None or given in extras() or given.isupper() else [  # or a placeholder
        f"no extra {given!r}"]
  if program == "python" and args[:2] == ["-m", "build"]:  # pyproject's wheel, into dist/
    return []
  if program == "python" and args and args[0].startswith(("benchmarks/", "tests/", "scripts/")):
    return sorted(used - script_flags(args[0]))
  if program.endswith("pip") and args[:1] == ["install"]:
    named = re.findall(r"\.\[([\w,]+)\]", " ".join(args))
    bad = [e for group in named for e in group.split(",") if e not in extras()]
    return ([f"pip install of the package by name, as if it were on PyPI: {args}"]
            if any(a.startswith("mjx_hopper") for a in args) else bad)
  if program in ("cd", "git"):
    return []
  return [f"a command this test does not know: {program}"]


def subcommands() -> set[str]:
  """The subcommands `mjx-hopper --help` lists, in its {a,b,...} line."""
  found = re.search(r"\{([\w,-]+)\}", cli_help([]))
  return set(found.group(1).split(",")) if found else set()


@pytest.mark.parametrize("page", PAGES)
def test_every_shell_command_on_the_page_exists(page):
  top = help_flags([])
  wrong = {" ".join(words): found for words in commands(page)
           if (found := problems(words, top))}
  assert not wrong, f"{page}: commands the CLI or pyproject do not have: {wrong}"


def test_the_readme_names_every_extra():
  with open(os.path.join(ROOT, "README.md")) as f:
    named = set(re.findall(r"`([\w-]+)`", f.read()))
  assert extras() <= named, f"the README does not name the extras {extras() - named}"


def test_the_pages_have_commands_to_check():
  assert len(commands("README.md")) >= 8
  assert sum(len(commands(p)) for p in PAGES) >= 30


@pytest.mark.slow
def test_the_brax_pages_code_runs_as_written_in_order(monkeypatch):
  with open(os.path.join(ROOT, "docs", "brax.md")) as f:
    blocks = re.findall(r"```python\n(.*?)```", f.read(), re.S)
  code = "\n".join(textwrap.dedent(block) for block in blocks)  # one sits in a list item
  # Its budget shrunk to two short epochs and short evaluation episodes; every other word as
  # the page has it.
  for budget, small in (("num_timesteps=2_000_000", "num_timesteps=1_024"),
                        ("num_evals=20", "num_evals=2"),
                        ("episode_length=1000", "episode_length=50")):
    assert code.count(budget) == 1
    code = code.replace(budget, small)
  monkeypatch.setattr(jax, "device_put_replicated", None, raising=False)  # restored after
  scope = {}
  with contextlib.redirect_stdout(io.StringIO()) as printed:
    exec(compile(code, "docs/brax.md", "exec"), scope)  # noqa: S102 - the page's own code
  # Brax's SAC trained on our env: its evaluations carry our reward terms, its losses finite.
  metrics = scope["metrics"]
  assert {f"eval/episode_{name}" for name in envs.REWARD_TERMS} <= set(metrics)
  for name in ("eval/episode_reward", "training/actor_loss", "training/critic_loss",
               "training/alpha_loss"):
    assert np.isfinite(metrics[name]), name
  assert len(printed.getvalue().splitlines()) == 2  # progress_fn at each evaluation
  models, in_axes = scope["heavier_torso"](scope["env"].sys, jax.random.split(
      jax.random.PRNGKey(0), 4))
  assert models.body_mass.shape == (4, scope["env"].mj_model.nbody)


def test_the_design_page_names_every_module():
  with open(os.path.join(ROOT, "docs", "design.md")) as f:
    text = f.read()
  named = set(re.findall(r"`(?:\w+/)?(\w+\.py)`", text))  # `run/loop.py`, or `loop.py` after it
  whole = set(re.findall(r"`(\w+)/`", text))  # a sub-package named as one (`store/`)
  package = os.path.join(ROOT, "mjx_hopper")
  modules = {os.path.basename(p) for p in glob.glob(os.path.join(package, "**", "*.py"),
                                                    recursive=True)
             if os.path.relpath(p, package).split(os.sep)[0] not in whole}
  assert modules - {"__init__.py"} <= named, f"docs/design.md omits {modules - named}"
