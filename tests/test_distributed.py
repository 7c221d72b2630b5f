"""The exchanges of a run over processes, against a stand-in for JAX's all-gather: every process
agrees on a phase before its flags count, and processes out of step say where each stands; and
an error as the one line a stopped process prints."""

import numpy as np
import pytest

from mjx_hopper.process import distributed, errors


def test_an_error_is_its_first_line_or_its_type():
  assert errors.first_line(ValueError(" bad value\nmore on it")) == "bad value"
  assert errors.first_line(OSError("disk full"), typed=True) == "OSError: disk full"
  assert errors.first_line(KeyError()) == errors.first_line(KeyError(), typed=True) == "KeyError"
  assert errors.first_line(ValueError("x" * 500), limit=300) == "x" * 300


def as_processes(monkeypatch, others):
  """This process as process 0 of 1 + len(others), the others sending what `others` makes of
  this process's exchange (its bytes, as each of them would send them)."""
  monkeypatch.setattr(distributed, "count", lambda: 1 + len(others))

  def allgather(mine):
    return np.stack([mine] + [other(mine.copy()) for other in others])
  monkeypatch.setattr(distributed.multihost_utils, "process_allgather", allgather)


def at(phase, *flags):
  """Another process's exchange: `phase` with `flags`."""
  def send(mine):
    mine[:] = 0
    mine[:len(phase)] = np.frombuffer(phase.encode(), np.uint8)
    mine[distributed.PHASE_BYTES:distributed.PHASE_BYTES + len(flags)] = flags
    return mine
  return send


@pytest.mark.parametrize("mine, theirs, agreed", [
    ((False, False), (False, False), (False, False)),
    ((True, False), (False, False), (True, False)),
    ((False, False), (False, True), (False, True)),
    ((True, True), (True, True), (True, True))])
def test_a_flag_is_true_where_any_process_holds_it(monkeypatch, mine, theirs, agreed):
  as_processes(monkeypatch, [at("after the chunk", *theirs)])
  assert distributed.agree("after the chunk", *mine) == agreed


def test_processes_out_of_step_say_where_each_stands(monkeypatch):
  as_processes(monkeypatch, [at("chunk", True), at("evaluation")])
  with pytest.raises(distributed.OutOfStep, match=r"^the processes are out of step \(process 0 "
                     r"at 'evaluation', process 1 at 'chunk', process 2 at 'evaluation'\)"):
    distributed.in_step("evaluation")
  as_processes(monkeypatch, [at("metrics")])
  with pytest.raises(distributed.OutOfStep, match="process 0 at 'chunk', process 1 at 'metrics'"):
    distributed.agree("chunk", True, False)
  as_processes(monkeypatch, [at("pbt")])
  with pytest.raises(distributed.OutOfStep, match="process 0 at 'pbt-x', process 1 at 'pbt'"):
    distributed.gather({"x": np.zeros(3)}, "pbt-x")


def test_every_exchange_is_one_size_and_a_long_phase_is_refused(monkeypatch):
  """Processes out of step exchange as many bytes, whatever their phases and flags, so that
  each reads the others' phase rather than the runtime aborting on a size mismatch."""
  sizes = []

  def allgather(mine):
    sizes.append(mine.nbytes)
    return np.stack([mine, mine])
  monkeypatch.setattr(distributed, "count", lambda: 2)
  monkeypatch.setattr(distributed.multihost_utils, "process_allgather", allgather)
  assert distributed.agree("lock", True) == (True,)
  distributed.in_step("evaluation")
  assert distributed.agree("after the chunk", True, False, True) == (True, False, True)
  assert distributed.agree("a", *[True] * distributed.MAX_FLAGS) == (True,) * 8
  assert len(sizes) == 4 and len(set(sizes)) == 1
  with pytest.raises(ValueError, match=r"phase 'x{33}' with 0 flags: at most 32 bytes"):
    distributed.in_step("x" * 33)
  with pytest.raises(ValueError, match="with 9 flags: at most 32 bytes and 8 flags"):
    distributed.agree("a", *[True] * 9)
  monkeypatch.setattr(distributed, "count", lambda: 1)
  assert distributed.agree("lock", True, False) == (True, False) and len(sizes) == 4
