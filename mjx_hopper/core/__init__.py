"""The core floor: the compiled trainer and the parts it is made of.

`train` holds the `TrainState` and the compiled chunk, refill and evaluation, and `start`
compiles a run's first programs; `evaluator`, `members` and `pbt` run the evaluations, keep the
members' record and take PBT's step; `replay` and `rollout` are the replay ring and episode
rollouts.
"""
