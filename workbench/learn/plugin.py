"""Light plugin: tells :func:`workbench.hydro.legmodel.load_leg_model` where learned models come from.

``load_leg_model("lstm")`` -> the registered champion FED-LSTM (see
:mod:`workbench.learn.registry`); ``load_leg_model("models:/fed-lstm@tuned")`` or
``"models:/fed-lstm/3"`` -> that registry version; ``load_leg_model("datasets/models/fed-lstm-16")``
-> the saved model folder at that path (what pipeline stages use: a path is a DVC dep). No torch
or mlflow import here.
"""

from workbench.hydro.legmodel import register_loader

register_loader("lstm", "workbench.learn.registry:load_champion")
# a prefix loader is registered under a name ending in ":"; it matches every "models:/..." spec
register_loader("models:", "workbench.learn.registry:load_model_uri")

try:  # a saved model folder by its path (cores without path loaders only know names and prefixes)
    from workbench.hydro.legmodel import register_path_loader

    register_path_loader("workbench.learn.registry:load_path")
except ImportError:  # pragma: no cover
    pass
