"""Array specs in the style of dm_env / acme: what an env takes and returns."""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class Array:
  """An array of a fixed shape and dtype."""

  shape: tuple[int, ...]
  dtype: np.dtype
  name: str = ""

  def __repr__(self) -> str:
    return f"Array(shape={self.shape}, dtype={np.dtype(self.dtype).name}, name={self.name!r})"


@dataclasses.dataclass(frozen=True, repr=False)
class BoundedArray(Array):
  """An array whose values lie in [minimum, maximum], elementwise."""

  minimum: np.ndarray = dataclasses.field(default_factory=lambda: np.array(-np.inf))
  maximum: np.ndarray = dataclasses.field(default_factory=lambda: np.array(np.inf))

  def __repr__(self) -> str:
    return (f"BoundedArray(shape={self.shape}, dtype={np.dtype(self.dtype).name}, "
            f"name={self.name!r}, minimum={np.asarray(self.minimum)}, "
            f"maximum={np.asarray(self.maximum)})")


@dataclasses.dataclass(frozen=True)
class EnvironmentSpec:
  """The three specs of an environment, as acme's `specs.make_environment_spec` gives them."""

  observations: Array
  actions: BoundedArray
  rewards: Array
