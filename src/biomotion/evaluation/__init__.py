"""Evaluation harness: every applicable metric on generated and real clips, tables, plots and reference values
(the metrics themselves live in `biomotion.metrics`)."""

from biomotion.data.clips import load_clip_set
from biomotion.evaluation.harness import (
    eval_command,
    evaluate,
    reference_command,
    reference_metrics,
)
from biomotion.metrics.clip_set import ClipSet

__all__ = ["ClipSet", "eval_command", "evaluate", "load_clip_set", "reference_command", "reference_metrics"]
