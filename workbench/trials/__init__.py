"""Open-water trials: track the robot's markers in overhead videos and score each trial per the contract.

Pure pieces work on arrays (``detect``, ``track``, ``clean``, ``geometry``, ``scoring``, ``compare``);
``video`` and ``trial`` read one trial's video, ``folder`` scores a whole trials folder, ``outputs``
writes scores.csv, summary.json and the rest. Entry points: :func:`score_trial` (one trial),
:func:`score_folder` (in memory) and :func:`run_scoring` (folder in, output folder out).
"""

from workbench.trials.folder import FolderResult, TrialFailure, score_folder
from workbench.trials.outputs import run_scoring
from workbench.trials.params import ScoringParams, ScoringSettings
from workbench.trials.trial import TrialResult, score_trial

__all__ = ["FolderResult", "ScoringParams", "ScoringSettings", "TrialFailure", "TrialResult", "run_scoring", "score_folder",
           "score_trial"]
