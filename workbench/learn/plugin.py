"""Light plugin: tells :func:`workbench.hydro.legmodel.load_leg_model` where learned models come from.

``load_leg_model("lstm")`` -> the registered champion FED-LSTM (see
:mod:`workbench.learn.registry`); ``load_leg_model("models:/fed-lstm@tuned")`` or
``"models:/fed-lstm/3"`` -> that registry version. No torch or mlflow import here.
"""

from workbench.hydro.legmodel import register_loader

register_loader("lstm", "workbench.learn.registry:load_champion")
# a prefix loader is registered under a name ending in ":"; it matches every "models:/..." spec
register_loader("models:", "workbench.learn.registry:load_model_uri")
