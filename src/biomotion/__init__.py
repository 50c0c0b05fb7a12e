"""biomotion: personalized, biomechanically plausible human motion.

Read captured motion, fit it to a subject-scaled OpenSim model, infer what the body did, and generate new motion
for a given person and action. ``import biomotion as bm``; ``bm.read(path)`` reads any supported file,
``bm.BodyModel.from_osim(path)`` loads a model and ``bm.analyze(motion, model, forces)`` runs the analysis.
Heavy parts (torch, the body model) load on first use.
"""

from importlib import import_module
from typing import Any

from biomotion.errors import BiomotionError, ConfigError, DataFormatError, ModelError
from biomotion.motion import GroundReaction, Markers, Motion
from biomotion.profile import InjuryRecord, Profile
from biomotion.trial import Labels, Trial

__version__ = "0.1.0"

_LAZY = {
    "read": ("biomotion.io.formats", "read_any"),
    "BodyModel": ("biomotion.body.model", "BodyModel"),
    "analyze": ("biomotion.analysis", "analyze"),
    "solve_ik": ("biomotion.ik.markers", "solve_ik"),
    "DatasetCache": ("biomotion.data.registry", "DatasetCache"),
}

__all__ = [
    "BiomotionError", "ConfigError", "DataFormatError", "ModelError",
    "GroundReaction", "Markers", "Motion", "InjuryRecord", "Profile", "Labels", "Trial", "__version__", *_LAZY,
]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        module, attribute = _LAZY[name]
        return getattr(import_module(module), attribute)
    raise AttributeError(f"module 'biomotion' has no attribute {name!r}")
