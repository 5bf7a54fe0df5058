"""Whole jobs over the pipeline: a replay of recorded logs into outputs, with its summary.

Above :mod:`fusion.sinks` (a job opens its outputs) and below :mod:`fusion.cli` (which only
parses arguments and prints): a user's script runs the same job as the command.

- :mod:`fusion.jobs.replay`: replay a log directory, a DATA-uart2 capture or a ROS bag.
- :mod:`fusion.jobs.plots`: the replay's trajectory and yaw plot (matplotlib).
- :mod:`fusion.jobs.engine`: coarse tasks in this process, worker processes or on Dask.
- :mod:`fusion.jobs.cluster`: a folder of logs replayed on a Dask cluster.
- :mod:`fusion.jobs.tune`: parameters from logs with truth, by k-fold cross-validation.
"""
