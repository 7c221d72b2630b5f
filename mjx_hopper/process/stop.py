"""Stopping a run between chunks: Ctrl-C, SIGTERM, or a request from code."""

import signal


class StopRequest:
  """Within `with`, Ctrl-C and SIGTERM set `requested` instead of stopping the process, so the
  loop can finish its chunk and save; a second Ctrl-C stops at once. `request` does the same
  from code, with the reason the run's last line gives."""

  def __enter__(self):
    self.requested, self.reason = False, "stopped by a signal"
    self._previous = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
      try:
        self._previous[sig] = signal.signal(sig, self._handle)
      except ValueError:  # not the main thread: signals stay as they are
        pass
    return self

  def request(self, reason: str) -> None:
    """Asks the loop to save and stop after its chunk, for `reason`."""
    self.requested, self.reason = True, reason

  def _handle(self, signum, frame):
    if self.requested and signum == signal.SIGINT:
      raise KeyboardInterrupt
    self.requested = True
    print(f"\n{signal.Signals(signum).name}: saving a checkpoint after this chunk",
          flush=True)

  def __exit__(self, *exc):
    for sig, handler in self._previous.items():
      signal.signal(sig, handler)
    return False
