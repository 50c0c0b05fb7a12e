"""Learned models and their formats: the motion tokenizer (`vqvae`), subject profiler, profile-action prior, action
vocabulary, conditioning inputs, foot contact and the generator bundle; trained by ``biomotion train``
(`biomotion.training`)."""

from biomotion.models.vqvae import EMAQuantizer, MotionVQVAE, VQVAEConfig

__all__ = ["EMAQuantizer", "MotionVQVAE", "VQVAEConfig"]
