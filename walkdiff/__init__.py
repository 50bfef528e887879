"""walkdiff: diffusion-based human motion synthesis with Lightning and MLflow."""

__version__ = "0.1.0"
