"""The compile ledger (`process.ledger`): what a process compiles, loads and traces, summed."""

import jax
import jax.numpy as jnp
import numpy as np

from mjx_hopper.process import ledger


def test_the_ledger_counts_what_a_process_compiles_and_the_trainers_noted(tmp_path, monkeypatch):
  path = tmp_path / "events.jsonl"
  monkeypatch.setenv(ledger.VARIABLE, str(path))
  ledger.start()  # once per process: a second call adds no second listener
  offset = float(np.random.default_rng().integers(1 << 30))  # a program no cache holds

  @jax.jit
  def f(x):
    return jnp.sin(x) * 2.0 + offset

  f(np.ones(3, np.float32)).block_until_ready()
  f(np.ones(3, np.float32)).block_until_ready()  # in memory: no event
  ledger.note("trainer", "Hopper d4pg x1 abc")
  ledger.note("trainer", "Hopper d4pg x1 abc")
  with open(path, "a") as out:
    out.write('{"event": "compi')  # a line cut short by a process killed as it wrote
  totals = ledger.summarise([path])
  assert (totals["programs"], totals["compiled"], totals["cache hits"]) == (1, 1, 0), totals
  assert totals["compile s"] > 0 and totals["trace s"] > 0 and totals["lower s"] > 0
  assert totals["trainers"] == {"Hopper d4pg x1 abc"}
  monkeypatch.delenv(ledger.VARIABLE)
  jax.jit(lambda x: x - offset)(np.ones(2, np.float32))
  assert ledger.summarise([path]) == totals  # nothing written while the variable is unset
