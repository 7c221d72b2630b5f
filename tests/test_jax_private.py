"""JAX's private API that mjx_hopper/process/jax_private.py uses is still there, as it was read."""

import subprocess
import sys

from mjx_hopper.process import jax_private

PROGRAM = """
from mjx_hopper.process import jax_private
before = jax_private.backends_started()  # JAX not imported yet
import jax
imported = jax_private.backends_started()
jax.devices()
print(before, imported, jax_private.backends_started())
"""


def test_backends_started_tells_whether_xla_still_reads_its_flags():
  assert jax_private.backends_started()  # conftest's set-up ran JAX
  done = subprocess.run([sys.executable, "-c", PROGRAM], check=True, capture_output=True,
                        text=True, env={"JAX_PLATFORMS": "cpu", "PATH": ""})
  assert done.stdout.split() == ["False", "False", "True"]
