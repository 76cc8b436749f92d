"""``hydra/launcher=ray``: each job of a sweep a Ray task on a cluster (conflictbench's, in the `cluster` extra).

Hydra's own Ray launcher pins ``cloudpickle<3`` and cannot be installed beside the simulator (it needs
``>=3``); this one is Hydra's launcher contract over today's Ray, nothing more: Ray schedules the jobs.
"""
