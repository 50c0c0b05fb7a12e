"""Inference-time biomechanical guidance (PG-BIG Sec. 3.3): losses and the staged latent refinement."""
