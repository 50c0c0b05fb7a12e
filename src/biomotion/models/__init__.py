"""Learned models of PG-BIG: the motion tokenizer (`vqvae`) and its training command (`train_tokenizer`)."""

from biomotion.models.vqvae import EMAQuantizer, MotionVQVAE, VQVAEConfig

__all__ = ["EMAQuantizer", "MotionVQVAE", "VQVAEConfig"]
