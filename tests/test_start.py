"""The start compiles only the programs a run needs: no eager one-op programs while the env, the
agent and the trainer are built."""

import json
import subprocess
import sys

# The programs lowered before the first chunk's row: the chunk, init and the refill that begins
# its envs, the evaluation (where it is traced beside the chunk's compile), the members'
# finiteness check, and while building the env, MJX's model and data and the reset's reward
# terms (envs.check_task). Not counted: the trainer's programs as lowered to be kept
# (core.kept), once, by the first process to build them.
MOST_PROGRAMS_BEFORE_FIRST_CHUNK = 8

PROGRAM = """
import json, sys
import jax
from mjx_hopper.faces import notebook
from mjx_hopper.run import loop

lowered = []
def listen(event, duration, fun_name="?", **kwargs):
  if (event == "/jax/core/compile/jaxpr_to_mlir_module_duration"
      and not fun_name.startswith("jit(kept_")):
    lowered.append(fun_name)
jax.monitoring.register_event_duration_secs_listener(listen)

def first_row(env_steps, metrics):
  print(json.dumps(lowered))
  sys.stdout.flush()
  return False

cfg = notebook.tiny(loop.RunConfig(env="Hopper", agent="d4pg", agent_defaults="cpu",
                                   out_dir=sys.argv[1]))
loop.run(cfg, progress=False, print_fn=lambda line: None, progress_fn=first_row)
"""


def test_the_start_compiles_no_eager_programs(tmp_path):
  done = subprocess.run([sys.executable, "-c", PROGRAM, str(tmp_path)], capture_output=True,
                        text=True, check=True)
  lowered = json.loads(done.stdout.strip().splitlines()[0])
  assert len(lowered) <= MOST_PROGRAMS_BEFORE_FIRST_CHUNK, lowered
  # The finiteness check compiles beside the chunk, not after it. (The evaluation is traced
  # after the chunk's compile on a small CPU, so it may or may not come before the first row.)
  assert {"jit(chunk)", "jit(finite_members)"} <= set(lowered), lowered
