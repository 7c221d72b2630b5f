"""Many processes, each of several threads, compiling MJX rollouts and writing them into one
JAX persistent compile cache at once: a search for the segfault that CI's test workers met in
the cache write (`put_executable_and_time` -> `executable.serialize()`). Half the programs are
the same in every process, so that processes write and read one entry at once. Needs only
jax, mujoco and mujoco-mjx (it runs where the project's other dependencies are missing):

    python scripts/cache_stress.py --processes 16 --threads 4 --rounds 6 --waves 2

Each wave starts on an empty cache; a process that dies prints its Python stack
(faulthandler), and the script exits 1 naming its exit status."""

import argparse
import faulthandler
import os
import shutil
import subprocess
import sys
import tempfile
import threading

ASSETS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "envs", "assets")
ROBOTS = ("hopper.xml", "walker2d.xml", "half_cheetah.xml", "ant.xml")


def compile_rollouts(tag: str, threads: int, rounds: int, folder: str) -> None:
  """This process's part: `threads` threads, each compiling and running `rounds` rollouts."""
  faulthandler.enable()
  import jax
  import jax.numpy as jnp
  import mujoco
  from mujoco import mjx
  jax.config.update("jax_compilation_cache_dir", folder)
  jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
  models = {name: mjx.put_model(mujoco.MjModel.from_xml_path(os.path.join(ASSETS, name)))
            for name in ROBOTS}

  def rollout(model, batch, length, scale):
    def run(key):
      data = jax.vmap(lambda _: mjx.make_data(model))(jnp.arange(batch))

      def step(d, k):
        d = d.replace(ctrl=scale * jax.random.uniform(k, d.ctrl.shape, minval=-1, maxval=1))
        d = jax.vmap(mjx.step, in_axes=(None, 0))(model, d)
        return d, d.qpos[:, 0]
      return jax.lax.scan(step, data, jax.random.split(key, length))[1]
    return jax.jit(run)

  def work(t):
    for r in range(rounds):
      shared = r % 2 == 0  # the same program in every process: concurrent writes of one key
      own = hash((tag, t, r))
      program = rollout(models[ROBOTS[(t + r) % len(ROBOTS)]],
                        batch=2 + (t if shared else own % 7), length=3 + r % 3,
                        scale=1.0 if shared else 0.5 + (own % 97) / 100)
      jax.block_until_ready(program(jax.random.PRNGKey(r)))

  workers = [threading.Thread(target=work, args=(t,)) for t in range(threads)]
  for w in workers:
    w.start()
  for w in workers:
    w.join()


def main() -> int:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--processes", type=int, default=8)
  parser.add_argument("--threads", type=int, default=4)
  parser.add_argument("--rounds", type=int, default=6)
  parser.add_argument("--waves", type=int, default=1)
  parser.add_argument("--worker", nargs=2, metavar=("TAG", "FOLDER"), help=argparse.SUPPRESS)
  args = parser.parse_args()
  if args.worker:
    compile_rollouts(args.worker[0], args.threads, args.rounds, args.worker[1])
    return 0
  failed = 0
  for wave in range(args.waves):
    folder = tempfile.mkdtemp(prefix="cache_stress_")
    procs = [subprocess.Popen([sys.executable, __file__, "--threads", str(args.threads),
                               "--rounds", str(args.rounds), "--worker", f"{wave}-{p}", folder])
             for p in range(args.processes)]
    codes = [proc.wait() for proc in procs]
    print(f"wave {wave}: {len(os.listdir(folder))} cache entries; exit statuses {codes}",
          flush=True)
    failed += sum(code != 0 for code in codes)
    shutil.rmtree(folder)
  return 1 if failed else 0


if __name__ == "__main__":
  sys.exit(main())
