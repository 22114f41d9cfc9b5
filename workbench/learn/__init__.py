"""Learned leg force models (FED-LSTM and variants): data windows, nets, training, search, evaluation.

Light at import: torch, lightning, mlflow and optuna are imported by the modules that need them
(``data``, ``nets``, ``module``, ``train``, ``tune``, ``tracking``), never here.
"""
