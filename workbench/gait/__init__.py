"""Gait optimisation (paper section IV): the problem, its objectives, fast leg wrenches, runs, export.

* :mod:`workbench.gait.space` — decision variables (paper Table II) and their mapping to gaits.
* :mod:`workbench.gait.objectives` — the paper's Table III objectives as pure functions of a trajectory.
* :mod:`workbench.gait.tabulate` — tabulated leg wrenches (one cycle per gait over a flow grid).
* :mod:`workbench.gait.problem` — the pymoo ``GaitProblem`` (a whole population per simulation).
* :mod:`workbench.gait.run` — NSGA-II and random search, ranking by the score S, the best eight.
* :mod:`workbench.gait.export` — the gait file (data contract section 5) and the controller file.
"""
