"""The lab chain in memory: one trial on its model → joint angles, torques, ground forces, COM/ZMP (`chain`), and
muscle activations of an analysed trial by static optimization (`activations`)."""

from biomotion.analysis.chain import Analysis, analyze, write_analysis

__all__ = ["Analysis", "analyze", "write_analysis"]
