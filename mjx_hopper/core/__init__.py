"""The core floor: the compiled trainer and the parts it is made of.

`train` holds `TrainConfig`, the `TrainState` and the compiled chunk, refill and evaluation, and
`start` compiles a run's first programs; `evaluator`, `members` and `pbt` run the evaluations,
keep the members' record and take PBT's step; `replay`, `rollout`, `parallel` and `fields` are
the replay ring, episode rollouts, device sharding and typed settings.
"""
