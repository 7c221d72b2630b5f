"""Moved to `mjx_hopper.agents.networks`: this import path stays, as the same module."""

import sys

from mjx_hopper.agents import networks

sys.modules[__name__] = networks
