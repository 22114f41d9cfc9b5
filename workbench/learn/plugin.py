"""Where learned leg models come from (kept for the DVC stages that list this file as a dependency).

The loaders are entries of the ``workbench.leg_models`` entry-point group in ``pyproject.toml``
(read by :mod:`workbench.hydro.legmodel`): ``load_leg_model("lstm")`` -> the registered champion
FED-LSTM (:func:`workbench.learn.registry.load_champion`); ``"models:/fed-lstm@tuned"`` or
``"models:/fed-lstm/3"`` -> that registry version (``load_model_uri``); a saved model folder by its
path, ``"datasets/models/fed-lstm-16"`` -> ``load_path``. Nothing registers here any more.
"""
