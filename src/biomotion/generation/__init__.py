"""Motion generation (`biomotion generate`): PG-BIG, personalized guidance for biomechanically informed generative
models (King, Maeyama, Maheshwari & McCulloch; profile- and action-conditioned VQ-VAE generation with
biomechanical guidance)."""
