"""biomotion: personalized, biomechanically plausible human motion.

Read captured motion, fit it to a subject-scaled OpenSim model, infer what the body did, and generate new motion
for a given person and action::

    import biomotion as bm

    trial = bm.read_trial("walk.trc")                       # markers (.trc/.c3d), coordinates (.mot), BVH
    model = bm.BodyModel.from_osim("subject_scaled.osim")
    result = bm.analyze_trial(trial, model=model, forces=bm.read("walk_grf.mot"))
    result.angles, result.torques, result.ground_reaction, result.dynamics.zmp
    no_plates = bm.analyze_trial(trial, model=model, forces=bm.learned_forces())  # GRF learned from plates

Every name in ``__all__`` is the Python call behind a ``biomotion`` command; each is imported on first use, so
``import biomotion`` stays light (no torch until something needs it).
"""

from importlib import import_module
from typing import Any

__version__ = "0.1.0"

_API = {
    # value types and errors
    "Motion": "biomotion.motion",
    "Markers": "biomotion.motion",
    "GroundReaction": "biomotion.motion",
    "Trial": "biomotion.trial",
    "Labels": "biomotion.trial",
    "Profile": "biomotion.profile",
    "InjuryRecord": "biomotion.profile",
    "BiomotionError": "biomotion.errors",
    "DataFormatError": "biomotion.errors",
    "ModelError": "biomotion.errors",
    "ConfigError": "biomotion.errors",
    # reading and writing (biomotion convert, inspect)
    "read": "biomotion.io.formats",
    "read_trial": "biomotion.io.formats",
    "describe": "biomotion.io.formats",
    "convert": "biomotion.analysis.convert",
    "read_profile": "biomotion.io.profiles",
    # the body and the lab chain (biomotion scale, retarget, analyze)
    "BodyModel": "biomotion.body.model",
    "Shape": "biomotion.body.shape",
    "read_ik_setup": "biomotion.io.setup",
    "solve_ik": "biomotion.ik.markers",
    "calibrate": "biomotion.ik.calibrate",
    "retarget": "biomotion.ik.retarget",
    "analyze": "biomotion.analysis.chain",
    "analyze_trial": "biomotion.analysis.trial",
    "TrialAnalysis": "biomotion.analysis.trial",
    # a whole study, and verdicts on motion (biomotion batch, check)
    "batch": "biomotion.analysis.batch",
    "load_study": "biomotion.analysis.study",
    "check": "biomotion.analysis.check",
    "learned_forces": "biomotion.models.ground_forces",
    "LearnedGroundReaction": "biomotion.models.ground_forces",
    "ShapeAdapter": "biomotion.models.shape_vae",
    # data, generation, evaluation, validation, viewing
    "DatasetCache": "biomotion.data.registry",
    "build_cache": "biomotion.data.registry",
    "generate": "biomotion.generation.request",
    "adapt": "biomotion.generation.adapt",
    "read_body": "biomotion.generation.adapt",
    "Control": "biomotion.guidance.control",
    "refine": "biomotion.generation.refinement",
    "Refined": "biomotion.generation.refinement",
    "evaluate": "biomotion.evaluation.harness",
    "eval_generation": "biomotion.evaluation.generation",
    "run_validation": "biomotion.validation.run",
    "view": "biomotion.viz.viewer",
}
_RENAMED = {"read": "read_any", "view": "view_command"}

__all__ = ["__version__", *_API]


def __getattr__(name: str) -> Any:
    if name in _API:
        value = getattr(import_module(_API[name]), _RENAMED.get(name, name))
        globals()[name] = value
        return value
    raise AttributeError(f"module 'biomotion' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(__all__)
