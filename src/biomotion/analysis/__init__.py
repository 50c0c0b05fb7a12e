"""The lab chain in memory: one trial on its model → joint angles, torques, ground forces, COM/ZMP, activations
(`trial.analyze_trial`), its inverse-dynamics core (`chain`), muscle activations by static optimization
(`activations`), and format conversion through a model (`convert`)."""

from biomotion.analysis.chain import Analysis, analyze, write_analysis
from biomotion.analysis.trial import TrialAnalysis, analyze_trial

__all__ = ["Analysis", "TrialAnalysis", "analyze", "analyze_trial", "write_analysis"]
