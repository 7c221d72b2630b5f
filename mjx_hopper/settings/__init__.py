"""The settings floor: what a run is asked to do.

`config` holds `RunConfig`, every setting with its default, type and help (the command line's
flags are made from them) and a sweep's checked grid; `presets` each robot's measured cpu and gpu
settings and budgets; `flags` the flags of `train` and `sweep`.
"""
