"""Gait optimisation (paper section IV): the problem, its objectives, fast leg wrenches, runs, export.

* :mod:`workbench.gait.space` — decision variables (paper Table II) and their mapping to gaits.
* :mod:`workbench.gait.objectives` — the paper's Table III objectives as pure functions of a trajectory.
* :mod:`workbench.gait.cycles`, :mod:`workbench.gait.tabulate` — tabulated leg wrenches (one steady
  cycle per gait shape over a flow grid) for models with memory.
* :mod:`workbench.gait.problem` — the pymoo ``GaitProblem`` (a whole population per simulation).
* :mod:`workbench.gait.run` — NSGA-II and random search, hypervolume, ranking by the score S.
* :mod:`workbench.gait.optimize` — one optimisation in memory (``optimize_task``), with the direct check.
* :mod:`workbench.gait.export`, :mod:`workbench.gait.plots`, :mod:`workbench.gait.tracking` — the gait
  file (data contract section 5), the controller file, PNGs, the MLflow run.
* :mod:`workbench.gait.config` — ``pipelines/gait.yaml`` as frozen settings.
"""
