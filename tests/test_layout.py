"""The source layout's rules, read from the code itself: imports point one way, and no comment
or docstring carries history (dates, machine names, links to the benchmark pages)."""

import ast
import io
import pathlib
import re
import tokenize

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "mjx_hopper"
LEAVES = ("agents", "envs")  # installed as mjx_hopper.agents, mjx_hopper.envs
# What agents/ and envs/ may import from mjx_hopper/ (or the floor's package holding one, whose
# __init__ imports nothing); everything else there is the host layer (run.loop, settings.config,
# core.evaluator, core.members, core.pbt, run.trainers, run.sweep, store, run.logger, faces.cli,
# faces.notebook, settings.presets, faces.export, ...), which uses the leaves and never the reverse.
SHARED = {"agents", "envs", "settings.fields", "process.parallel"}


def _floor(name: str) -> tuple[str, ...]:
  """The modules in mjx_hopper/NAME/, as dotted names under mjx_hopper (its __init__ as NAME)."""
  return tuple(sorted(".".join(path.relative_to(PACKAGE).with_suffix("").parts)
                      .removesuffix(".__init__") for path in (PACKAGE / name).rglob("*.py")))


# The host layer's floors, lowest first: each a sub-package of mjx_hopper/ named for what it owns
# (docs/design.md), its modules those of its folder. A module imports only from its own floor and
# those below, and from agents/ and envs/.
FLOORS = {name: _floor(name) for name in ("process", "settings", "core", "store", "run", "faces")}

HISTORY = re.compile(r"\b\d{4}-\d{2}-\d{2}\b|H100|H200|\b2 cores\b|\b2-core\b|BENCHMARKS\.md"
                     r"|history\.md", re.IGNORECASE)


def _python_files(*folders: str) -> list[pathlib.Path]:
  return sorted(p for folder in folders for p in (ROOT / folder).rglob("*.py"))


def _package(path: pathlib.Path) -> list[str]:
  """The dotted package a file of agents/ or envs/ belongs to, as its parts."""
  folder = path.relative_to(ROOT).parent.parts
  return ["mjx_hopper", *folder]


def imported_modules(source: str, package: list[str]) -> list[tuple[int, str, str]]:
  """(line, absolute module, the import as written) for every module an import in `source`
  names, with relative imports resolved against `package`; `from a import b` yields both
  `a` and `a.b`, since `b` may be a module."""
  found = []
  for node in ast.walk(ast.parse(source)):
    text = ast.get_source_segment(source, node) or ""
    if isinstance(node, ast.Import):
      found += [(node.lineno, alias.name, text) for alias in node.names]
    elif isinstance(node, ast.ImportFrom):
      if node.level:
        base = package[:len(package) - node.level + 1]
        module = ".".join(base + ([node.module] if node.module else []))
      else:
        module = node.module
      found.append((node.lineno, module, text))
      found += [(node.lineno, f"{module}.{alias.name}", text) for alias in node.names]
    elif (isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant)
          and isinstance(node.args[0].value, str)
          and ast.unparse(node.func) in ("importlib.import_module", "import_module",
                                         "__import__")):
      found.append((node.lineno, node.args[0].value, text))
  return found


def _shared(name: str) -> bool:
  """Whether the module NAME of mjx_hopper is SHARED, or is a folder holding one of them."""
  return any(s == name or s.startswith(f"{name}.") for s in SHARED)


def host_imports(source: str, package: list[str]) -> list[tuple[int, str, str]]:
  """(line, host module, the import as written) for each import in `source` of a mjx_hopper
  module outside SHARED; a host module is named under mjx_hopper, as a floor's module (core.pbt)
  or a top-level one (checkpoint), and a floor's package is not named beside its module."""
  bad = {}
  for line, module, text in imported_modules(source, package):
    parts = module.split(".")
    if parts[0] == "mjx_hopper" and len(parts) > 1:
      name = ".".join(parts[1:3] if parts[1] in FLOORS else parts[1:2])
      if not _shared(name):
        bad[line, name] = text
  return [(line, name, text) for (line, name), text in sorted(bad.items())
          if not any(at == line and other.startswith(f"{name}.") for at, other in bad)]


@pytest.mark.parametrize("source", [
    "import mjx_hopper.run.loop",
    "import mjx_hopper.run.sweep as sweep",
    "from mjx_hopper import checkpoint",
    "from mjx_hopper.settings import fields, config",
    "from mjx_hopper.settings.presets import ROBOT_PRESETS",
    "from mjx_hopper.run.trainers.sub import x",
    "from ..faces import cli",
    "from ..faces.notebook import tiny",
    "from ..settings import config",
    "import importlib\nimportlib.import_module('mjx_hopper.core.evaluator')",
    "def f():\n  from mjx_hopper.core import pbt",
])
def test_a_host_import_is_found_in_every_form(source):
  assert len(host_imports(source, ["mjx_hopper", "agents"])) == 1, source


@pytest.mark.parametrize("source", [
    "import mjx_hopper",
    "from mjx_hopper.process import parallel",
    "from mjx_hopper.settings.fields import check_types",
    "from mjx_hopper.agents import distributional, networks",
    "from mjx_hopper.envs.base import LocomotionEnv",
    "from . import critics",
    "from .base import Agent",
    "from .. import envs",
    "import jax.numpy as jnp",
])
def test_a_shared_import_passes(source):
  assert host_imports(source, ["mjx_hopper", "agents"]) == [], source


def test_a_host_import_reports_its_line_and_text():
  source = "import jax\nfrom mjx_hopper.settings import config, fields, presets\n"
  text = "from mjx_hopper.settings import config, fields, presets"
  assert host_imports(source, ["mjx_hopper", "envs"]) == [(2, "settings.config", text),
                                                          (2, "settings.presets", text)]


def test_agents_and_envs_import_nothing_of_the_host_layer():
  files = _python_files(*LEAVES)
  assert len(files) > 10, files
  bad = [f"{path.relative_to(ROOT)}:{line}: {text}  (mjx_hopper.{name})"
         for path in files for line, name, text in host_imports(path.read_text(), _package(path))]
  assert not bad, ("agents/ and envs/ may import only mjx_hopper."
                   f"{{{', '.join(sorted(SHARED))}}} of the package, not the host layer:\n"
                   + "\n".join(bad))


def history_in(source: str) -> list[tuple[int, str]]:
  """(line, text) of each comment or docstring line of `source` that HISTORY matches."""
  hits = []
  for token in tokenize.generate_tokens(io.StringIO(source).readline):
    if token.type == tokenize.COMMENT and HISTORY.search(token.string):
      hits.append((token.start[0], token.string.strip()))
  for node in ast.walk(ast.parse(source)):
    if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
      if ast.get_docstring(node, clean=False) is None:
        continue
      first = node.body[0].value
      for offset, text in enumerate(first.value.splitlines()):
        if HISTORY.search(text):
          hits.append((first.lineno + offset, text.strip()))
  return sorted(hits)


@pytest.mark.parametrize("source", [
    "x = 1  # seen 2026-11-26",
    "# on an H100\n",
    "def f():\n  '''Fast on h200s.'''",
    "class A:\n  '''Sized for 2 cores.'''",
    "'''Module.\n\nThe 2-core runner (BENCHMARKS.md).'''",
    "# docs/benchmark-history.md, 'Choosing'\n",
])
def test_history_is_found_in_comments_and_docstrings(source):
  assert history_in(source), source


def test_history_reports_the_docstring_line():
  assert history_in("'''One.\n\nTwo, on an H100.'''\nx = 1\n") == [(3, "Two, on an H100.")]


def test_strings_and_names_are_not_history():
  assert history_in("KIND = 'nvidia-h100-x1'\nwhy = f(date='2026-11-26')\n") == []


@pytest.mark.parametrize("path", _python_files("mjx_hopper", *LEAVES),
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_no_history_in_comments_or_docstrings(path):
  hits = history_in(path.read_text())
  assert not hits, (f"{path.relative_to(ROOT)} has history (dates, machine names, benchmark-page "
                    "links) in comments or docstrings; figures belong in benchmarks/results/:\n"
                    + "\n".join(f"  line {line}: {text}" for line, text in hits))


def test_every_python_file_parses_on_this_python():
  # The floor job runs this on the oldest Python admitted, whose grammar is narrower (3.11's
  # f-strings cannot reuse their own quotes inside, for one).
  for path in _python_files("mjx_hopper", *LEAVES, "tests", "benchmarks", ".ci"):
    ast.parse(path.read_text(), str(path.relative_to(ROOT)))


def _module_name(path: pathlib.Path) -> str:
  """The dotted name a source file imports as (agents/ and envs/ install under mjx_hopper)."""
  parts = list(path.relative_to(ROOT).with_suffix("").parts)
  if parts[0] in LEAVES:
    parts.insert(0, "mjx_hopper")
  return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph(sources: dict[str, str], packages: set[str]) -> dict[str, set[str]]:
  """{module: the modules of `sources` it imports}, at any depth of its code (a function's
  imports too). `from a import b` is an import of the module a.b where there is one, else of a;
  `packages` are the names whose source is an __init__.py."""
  graph = {}
  for name, source in sources.items():
    package = name.split(".") if name in packages else name.split(".")[:-1]
    found = set()
    for node in ast.walk(ast.parse(source)):
      if isinstance(node, ast.Import):
        found |= {alias.name for alias in node.names}
      elif isinstance(node, ast.ImportFrom):
        base = ".".join(package[:len(package) - node.level + 1] + [node.module or ""]
                        if node.level else [node.module])
        base = base.rstrip(".")
        found |= {f"{base}.{a.name}" if f"{base}.{a.name}" in sources else base
                  for a in node.names}
    graph[name] = {m for m in found if m in sources and m != name}
  return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
  """The cycles a depth-first walk of `graph` meets, each as modules from one back to itself;
  none if and only if the graph has no cycle."""
  found, state = [], {}  # state: 1 while on the walk's path, 2 once left

  def visit(path: list[str]) -> None:
    state[path[-1]] = 1
    for nxt in sorted(graph[path[-1]]):
      if state.get(nxt) == 1:
        found.append(path[path.index(nxt):] + [nxt])
      elif nxt not in state:
        visit(path + [nxt])
    state[path[-1]] = 2
  for node in sorted(graph):
    if node not in state:
      visit([node])
  return found


def test_the_import_graph_finds_cycles_through_function_imports():
  sources = {"p": "", "p.a": "from p import b", "p.b": "def f():\n  from . import c",
             "p.c": "import p.a", "p.d": "from p.a import x"}
  graph = import_graph(sources, {"p"})
  assert graph == {"p": set(), "p.a": {"p.b"}, "p.b": {"p.c"}, "p.c": {"p.a"}, "p.d": {"p.a"}}
  assert cycles(graph) == [["p.a", "p.b", "p.c", "p.a"]]
  assert cycles({**graph, "p.c": set()}) == []


def package_graph() -> dict[str, set[str]]:
  """import_graph of the installed package: mjx_hopper/, agents/ and envs/."""
  files = _python_files("mjx_hopper", *LEAVES)
  sources = {_module_name(path): path.read_text() for path in files}
  packages = {_module_name(path) for path in files if path.name == "__init__.py"}
  return import_graph(sources, packages)


def test_the_package_has_no_import_cycle():
  graph = package_graph()
  assert graph["mjx_hopper.run.opening"] >= {"mjx_hopper.run.trainers",
                                            "mjx_hopper.core.evaluator"}
  found = cycles(graph)
  assert not found, ("modules that import each other, at any depth of their code (a cycle "
                     "works only while the order of imports allows it):\n"
                     + "\n".join(" -> ".join(cycle) for cycle in found))


def floor_breaches(graph: dict[str, set[str]], floors: dict[str, tuple[str, ...]],
                   package: str = "mjx_hopper") -> list[str]:
  """Each import in `graph` of a module of `package` on a higher floor than the importer's, as
  "importer (floor) -> imported (floor)"; modules outside `floors` are not checked."""
  level = {f"{package}.{m}": (i, name) for i, (name, modules) in enumerate(floors.items())
           for m in modules}
  return [f"{a} ({level[a][1]}) -> {b} ({level[b][1]})" for a in sorted(graph) if a in level
          for b in sorted(graph[a]) if b in level and level[b][0] > level[a][0]]


def test_an_import_from_a_higher_floor_is_found():
  graph = {"p.a": {"p.b", "p.c"}, "p.b": {"p.a"}, "p.c": set(), "p.x": {"p.c"}}
  floors = {"low": ("a", "c"), "high": ("b",)}
  assert floor_breaches(graph, floors, "p") == ["p.a (low) -> p.b (high)"]


def test_each_floor_imports_only_the_floors_below_it():
  graph = package_graph()
  host = sorted(m.removeprefix("mjx_hopper.") for m in graph
                if m != "mjx_hopper" and m.split(".")[1] not in LEAVES)
  folders = sorted(path.parent.name for path in PACKAGE.glob("*/__init__.py"))
  assert folders == sorted(FLOORS), "every sub-package of mjx_hopper/ is a floor (FLOORS)"
  outside = [m for m in host if m.split(".")[0] not in FLOORS]
  assert not outside, f"host modules outside the floors' folders (mjx_hopper/FLOOR/): {outside}"
  placed = [m for modules in FLOORS.values() for m in modules]
  assert sorted(placed) == host, "every module of the host layer is on one floor (FLOORS)"
  breaches = floor_breaches(graph, FLOORS)
  assert not breaches, "imports from a higher floor:\n" + "\n".join(breaches)
