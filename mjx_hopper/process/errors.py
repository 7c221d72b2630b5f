"""An error as one line, for the one-line reports that a run prints where it stops."""


def first_line(error: BaseException, typed: bool = False, limit: int = 300) -> str:
  """The first line of `error`'s message, at most `limit` characters, after its type's name
  where `typed` ("OSError: disk full"); its type's name alone where the message is empty."""
  text = str(error).strip()
  if not text:
    return type(error).__name__
  line = text.splitlines()[0][:limit]
  return f"{type(error).__name__}: {line}" if typed else line
