"""The run floor: a run from its settings to its folder, over the floors below.

`opening` resolves a run's settings once, restores its checkpoint and assembles its parts; `loop`
is `run`, `resume` and the host loop between chunks; `runs` makes a run's trainer and state and
reads a saved run back; `sweep`, `curves` and `logger` rank a sweep's members, draw learning
curves and write the log's rows.
"""
