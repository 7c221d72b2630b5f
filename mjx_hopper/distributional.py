"""Moved to `mjx_hopper.agents.distributional`: this import path stays, as the same module."""

import sys

from mjx_hopper.agents import distributional

sys.modules[__name__] = distributional
