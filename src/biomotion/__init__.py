"""biomotion: personalized, biomechanically plausible human motion.

Read captured motion, fit it to a subject-scaled OpenSim model, infer what the body did, and generate new motion
for a given person and action. ``import biomotion as bm``.
"""

from biomotion.errors import BiomotionError, ConfigError, DataFormatError, ModelError
from biomotion.motion import GroundReaction, Markers, Motion
from biomotion.profile import InjuryRecord, Profile
from biomotion.trial import Labels, Trial

__version__ = "0.1.0"

__all__ = [
    "BiomotionError", "ConfigError", "DataFormatError", "ModelError",
    "GroundReaction", "Markers", "Motion", "InjuryRecord", "Profile", "Labels", "Trial", "__version__",
]
