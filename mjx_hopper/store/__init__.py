"""The store: orbax checkpoints of the whole TrainState, beside a JSON item with the run's
config.

`items` lays out a step (and its format version), `manifests` records each finished step's
files to tell a damaged one apart, `failures` cleans up after a save that fails, and `saver`
saves a run as it trains and reads back the newest step that reads.
"""

from mjx_hopper.store.failures import SaveFailed
from mjx_hopper.store.items import (ConfigMismatch, FormatMismatch, check_format, has_best,
                                    manager, read_agent, read_best, read_config, read_state,
                                    save)
from mjx_hopper.store.manifests import damage, wait_and_record
from mjx_hopper.store.saver import Resumed, Saver, check_config, load_newest, read_latest

__all__ = ["ConfigMismatch", "FormatMismatch", "Resumed", "SaveFailed", "Saver", "check_config",
           "check_format", "damage", "has_best", "load_newest", "manager", "read_agent",
           "read_best", "read_config", "read_latest", "read_state", "save", "wait_and_record"]
