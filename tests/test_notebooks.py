"""The notebooks run top to bottom (in their short mode)."""

import pathlib

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = sorted((pathlib.Path(__file__).parent.parent / "notebooks").glob("*.ipynb"))


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs(path, tmp_path, monkeypatch):
  monkeypatch.setenv("MJX_HOPPER_SHORT", "1")  # the kernel also inherits conftest's XLA_FLAGS
  notebook = nbformat.read(path, as_version=4)
  # Run in a scratch copy of the folder so outputs (videos) do not land in the repository.
  for other in path.parent.iterdir():
    if other.is_file():
      (tmp_path / other.name).write_bytes(other.read_bytes())
  NotebookClient(notebook, timeout=600, kernel_name="python3",
                 resources={"metadata": {"path": str(tmp_path)}}).execute()
  outputs = "".join(o.get("text", "") for c in notebook.cells for o in c.get("outputs", []))
  assert "env steps/s" in outputs
  assert not any(o.get("output_type") == "error" for c in notebook.cells
                 for o in c.get("outputs", []))
