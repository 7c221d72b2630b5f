"""Which processes of a run over JAX's distributed runtime load their programs from the
persistent compile cache: the same two-process run, twice, on one cache folder, each process
compiling one program sharded over both processes' CPU devices. Needs only jax:

    python scripts/cache_across_processes.py

On CPU (jax 0.12) the second run's process 0 loads its program and process 1 compiles it again:
JAX writes entries from process 0 only, and on CPU each process's key differs (JAX strips the
device assignment from the key on GPUs only), so every process but the first compiles afresh
at each start. Exits 1 when some process of the second run compiled."""

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile

PROCESS = """
import json, sys
import jax, jax.numpy as jnp
from jax.sharding import Mesh, NamedSharding, PartitionSpec
index, port, folder = int(sys.argv[1]), sys.argv[2], sys.argv[3]
jax.config.update("jax_cpu_collectives_implementation", "gloo")
jax.config.update("jax_compilation_cache_dir", folder)
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
events = []  # a program loaded from the cache is also a "backend compile" (the load)
jax.monitoring.register_event_listener(lambda name, **_: events.append(name))
jax.monitoring.register_event_duration_secs_listener(lambda name, _, **__: events.append(name))
jax.distributed.initialize(f"localhost:{port}", 2, index)
sharding = NamedSharding(Mesh(jax.devices(), ("d",)), PartitionSpec("d"))
x = jax.make_array_from_process_local_data(sharding, jnp.ones(4))
jax.block_until_ready(jax.jit(lambda x: jnp.sin(x) * 2 + x.sum(), out_shardings=sharding)(x))
hits = events.count("/jax/compilation_cache/cache_hits")
print(json.dumps({"hits": hits,
                  "misses": events.count("/jax/core/compile/backend_compile_duration") - hits}))
jax.distributed.shutdown()
"""


def run(folder: str) -> list[dict]:
  """One run of two processes of one CPU device each; each process's cache hits and misses."""
  with socket.socket() as s:
    s.bind(("localhost", 0))
    port = s.getsockname()[1]
  env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=1",
             JAX_PLATFORMS="cpu")
  procs = [subprocess.Popen([sys.executable, "-c", PROCESS, str(i), str(port), folder], env=env,
                            stdout=subprocess.PIPE, text=True) for i in range(2)]
  outs = [proc.communicate(timeout=300)[0] for proc in procs]
  if any(proc.returncode for proc in procs):
    sys.exit(f"a process failed: exit statuses {[proc.returncode for proc in procs]}")
  return [json.loads(out.strip().splitlines()[-1]) for out in outs]


def main() -> int:
  argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args()
  with tempfile.TemporaryDirectory() as folder:
    first, second = run(folder), run(folder)
  for name, counts in (("first run", first), ("second run", second)):
    print(name + ": " + "; ".join(f"process {i} {c['hits']} loaded, {c['misses']} compiled"
                                  for i, c in enumerate(counts)))
  return 1 if any(c["misses"] for c in second) else 0


if __name__ == "__main__":
  sys.exit(main())
