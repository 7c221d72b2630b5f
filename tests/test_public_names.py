"""The code's public face, read from the source: every public name of mjx_hopper/, envs/ and
agents/ has a docstring (an override of a documented method has its base's), and benchmarks/
reaches the package through public names only."""

import ast
import importlib
import pathlib
import types

ROOT = pathlib.Path(__file__).resolve().parent.parent
PACKAGES = {"mjx_hopper": "mjx_hopper", "envs": "mjx_hopper.envs", "agents": "mjx_hopper.agents"}
DEFINITIONS = (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)


def is_setter(function) -> bool:
  """Whether `function` is a property's setter or deleter, which its getter documents."""
  return any(isinstance(d, ast.Attribute) and d.attr in ("setter", "deleter")
             for d in function.decorator_list)


def public_definitions(source: str):
  """(class name or None, name, has a docstring) of each public function and class at the top
  of `source`, and of each public method of its public classes."""
  for node in ast.parse(source).body:
    if isinstance(node, DEFINITIONS) and not node.name.startswith("_"):
      yield None, node.name, ast.get_docstring(node) is not None
      for item in node.body if isinstance(node, ast.ClassDef) else ():
        if (isinstance(item, DEFINITIONS[:2]) and not item.name.startswith("_")
            and not is_setter(item)):
          yield node.name, item.name, ast.get_docstring(item) is not None


def documented_in_a_base(module: str, class_name: str, name: str) -> bool:
  """Whether a base of the class overrides a method (or property) `name` that has a docstring."""
  cls = getattr(importlib.import_module(module), class_name)
  kinds = (types.FunctionType, property, classmethod, staticmethod)
  return any(isinstance(base.__dict__.get(name), kinds) and base.__dict__[name].__doc__
             for base in cls.__mro__[1:])


def test_public_definitions_are_read_from_the_source():
  source = ('def f():\n  """Doc."""\ndef _g(): pass\nclass C:\n  def m(self): pass\n'
            '  def _n(self): pass\n  @property\n  def p(self):\n    """Doc."""\n'
            '  @p.setter\n  def p(self, v): pass\n')
  assert list(public_definitions(source)) == [(None, "f", True), (None, "C", False),
                                              ("C", "m", False), ("C", "p", True)]


def test_every_public_name_has_a_docstring():
  missing = []
  for folder, package in PACKAGES.items():
    for path in sorted((ROOT / folder).rglob("*.py")):  # the floors' sub-packages too
      parts = path.relative_to(ROOT / folder).with_suffix("").parts
      module = ".".join((package, *parts)).removesuffix(".__init__")
      for class_name, name, documented in public_definitions(path.read_text()):
        if documented or (class_name and documented_in_a_base(module, class_name, name)):
          continue
        missing.append(f"{path.relative_to(ROOT)}: {class_name + '.' if class_name else ''}{name}")
  assert not missing, "public names without a docstring:\n" + "\n".join(missing)


# A NamedTuple's public methods, named with an underscore so as not to clash with its fields.
NAMED_TUPLE_METHODS = ("_replace", "_asdict", "_fields", "_make")


def private_names(source: str) -> list[str]:
  """What `source` reaches by a private name: `x._name`, or `from m import _name`."""
  found = []
  for node in ast.walk(ast.parse(source)):
    if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not (
        node.attr.startswith("__") or node.attr in NAMED_TUPLE_METHODS
        or ast.unparse(node.value) == "self"):
      found.append(ast.unparse(node))
    elif isinstance(node, ast.ImportFrom):
      found += [alias.name for alias in node.names if alias.name.startswith("_")]
  return found


def test_benchmarks_use_public_names_only():
  assert sorted(private_names("import m\nm._x()\nself._y = 1\nfrom m import _z, w\n"
                              "m.__version__\ns._replace(a=1)")) == ["_z", "m._x"]
  used = {path.name: private_names(path.read_text())
          for path in sorted((ROOT / "benchmarks").glob("*.py"))}
  assert not {name: found for name, found in used.items() if found}
