"""Type checks for the settings dataclasses, refusing a wrong type in one line."""

from __future__ import annotations

import dataclasses
import types
import typing

import numpy as np


def _kind(hint) -> str:
  """A type hint as users read it: 'float', 'tuple of int', 'float or None'."""
  args = typing.get_args(hint)
  if typing.get_origin(hint) in (typing.Union, types.UnionType):
    return " or ".join(_kind(a) for a in args)
  if typing.get_origin(hint) is tuple:
    return f"tuple of {_kind(args[0])}"
  return "None" if hint is type(None) else hint.__name__


def convert(hint, value):
  """`value` as `hint` asks (an int is a float; a list a tuple), or raise TypeError."""
  origin, args = typing.get_origin(hint), typing.get_args(hint)
  if origin in (typing.Union, types.UnionType):
    for arg in args:
      try:
        return convert(arg, value)
      except TypeError:
        pass
    raise TypeError
  if origin is tuple:
    if not isinstance(value, (tuple, list)):
      raise TypeError
    return tuple(convert(args[0], v) for v in value)
  if hint is type(None):
    if value is not None:
      raise TypeError
    return None
  if hint is bool:
    if not isinstance(value, (bool, np.bool_)):
      raise TypeError
    return bool(value)
  if hint is int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
      raise TypeError
    return int(value)
  if hint is float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer,
                                                                      np.floating)):
      raise TypeError
    return float(value)
  if not isinstance(value, hint):
    raise TypeError
  return value


def check_types(cfg) -> None:
  """Checks each field of the frozen dataclass `cfg` against its type hint, converting an int
  for a float and a list for a tuple in place; a ValueError names the first bad field."""
  hints = typing.get_type_hints(type(cfg))
  for field in dataclasses.fields(cfg):
    value = getattr(cfg, field.name)
    try:
      converted = convert(hints[field.name], value)
    except TypeError:
      raise ValueError(f"{field.name} takes a {_kind(hints[field.name])}, got {value!r}") from None
    if converted is not value:
      object.__setattr__(cfg, field.name, converted)


def setting(default, help: str, flag: bool = True):
  """A dataclass field with its help text; the command line offers it as --name when `flag`."""
  meta = {"help": help, "flag": flag}
  if isinstance(default, dict):
    return dataclasses.field(default_factory=dict, metadata=meta)
  return dataclasses.field(default=default, metadata=meta)
