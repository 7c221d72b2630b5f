"""Prints pip constraints that pin each runtime dependency of pyproject.toml (the argument) to
its lower bound: `name>=X,<Y` becomes `name==X`. A dependency without one is an error."""

import re
import sys
import tomllib

with open(sys.argv[1], "rb") as f:
  dependencies = tomllib.load(f)["project"]["dependencies"]
for requirement in dependencies:
  name = re.match(r"[A-Za-z0-9._-]+", requirement).group()
  floor = re.search(r">=\s*([^,;\s]+)", requirement)
  if floor is None:
    sys.exit(f"{requirement!r} in pyproject.toml has no lower bound (>=X) to pin the floor job to")
  print(f"{name}=={floor.group(1)}")
