"""The settings floor: what a run is asked to do.

`config` holds `RunConfig`, every setting with its default, type and help (the command line's
flags are made from them) and a sweep's checked grid; `training` the trainer's `TrainConfig` and
`PBT`; `plan` a run's settings resolved once, at its start, into the frozen `Plan` that
everything after reads; `presets` each robot's measured cpu and gpu settings and budgets;
`flags` the flags of `train` and `sweep`; `fields` typed settings, which the agents' and tasks'
configs use too. It imports nothing from the floors above it.
"""
