"""Host-side logging between compiled chunks: a terminal line every `time_delta` seconds (like
acme's TerminalLogger) and a CSV of every logged row."""

from __future__ import annotations

import csv
import math
import os
import time
from typing import Callable


class Logger:
  """Writes every row to `csv_path`, and prints one every `time_delta` seconds (and the rows
  passed with force=True). The CSV's columns are those of the first row plus any added later
  (the file is rewritten when a new column appears)."""

  def __init__(self, csv_path: str | None, time_delta: float = 10.0,
               print_fn: Callable[[str], None] = print, label: str = "train"):
    self.csv_path, self.time_delta, self.print_fn, self.label = (csv_path, time_delta, print_fn,
                                                                 label)
    self.rows: list[dict] = []
    self.columns: list[str] = []
    self._last_print = -math.inf
    if csv_path:
      os.makedirs(os.path.dirname(os.path.abspath(csv_path)), exist_ok=True)
      if os.path.exists(csv_path):  # a resumed run appends to its log
        with open(csv_path, newline="") as f:
          reader = csv.DictReader(f)
          self.columns = list(reader.fieldnames or [])
          self.rows = list(reader)

  def write(self, row: dict, force: bool = False) -> None:
    row = {k: _plain(v) for k, v in row.items()}
    self.rows.append(row)
    if self.csv_path:
      self._write_csv(row)
    now = time.monotonic()
    if force or now - self._last_print >= self.time_delta:
      self._last_print = now
      self.print_fn(f"[{self.label}] " + " | ".join(f"{k} = {_fmt(v)}" for k, v in row.items()))

  def _write_csv(self, row: dict) -> None:
    new = [k for k in row if k not in self.columns]
    if new or not os.path.exists(self.csv_path):
      self.columns += new
      with open(self.csv_path, "w", newline="") as f:
        writer = csv.DictWriter(f, self.columns)
        writer.writeheader()
        writer.writerows(self.rows)
      return
    with open(self.csv_path, "a", newline="") as f:
      csv.DictWriter(f, self.columns).writerow(row)


def _plain(value):
  try:
    return float(value) if not isinstance(value, (int, str)) else value
  except (TypeError, ValueError):
    return value


def _fmt(value) -> str:
  if isinstance(value, float):
    return f"{value:,.0f}" if abs(value) >= 1000 else f"{value:.4g}"
  return f"{value:,}" if isinstance(value, int) else str(value)
