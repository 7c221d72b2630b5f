"""The store: orbax checkpoints of the whole TrainState, beside a JSON item with the run's
config.

`items` lays out a step (and its format version), `manifests` records each finished step's
files to tell a damaged one apart, `failures` cleans up after a save that fails, and `saver`
saves a run as it trains and resumes it from the newest step that reads.
"""

from mjx_hopper.store.failures import SaveFailed
from mjx_hopper.store.items import (ConfigMismatch, FormatMismatch, check_format, has_best,
                                    manager, read_config, restore, restore_agent, restore_best,
                                    save)
from mjx_hopper.store.manifests import damage, finish
from mjx_hopper.store.saver import Resumed, Saver, load_newest, resume

__all__ = ["ConfigMismatch", "FormatMismatch", "Resumed", "SaveFailed", "Saver", "check_format",
           "damage", "finish", "has_best", "load_newest", "manager", "read_config", "restore",
           "restore_agent", "restore_best", "resume", "save"]
