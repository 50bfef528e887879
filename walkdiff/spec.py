"""What a model needs to know of its data, shared by `walkdiff.data` and `walkdiff.models` from below.

The skeleton profile (`walkdiff.motion.profile`) travels beside it: too large for a hyperparameter, it is
handed over by the data module when training starts and saved in every checkpoint.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import roma
import torch

from walkdiff.motion.skeleton import Motion


@dataclass(frozen=True)
class DataSpec:
    """Feature layout, labels, window and frame rate of a motion dataset; linked into models by the CLI."""

    dataset: str
    feature_dim: int
    num_joints: int
    window: int
    fps: float
    styles: tuple[str, ...]
    contents: tuple[str, ...]


@dataclass(frozen=True)
class SpeechSpec:
    """What DiffMotion needs to know about its data; linked into the model by the CLI."""

    dataset: str
    feature_dim: int  # pose numbers per frame
    num_joints: int  # joints modelled
    window: int  # frames per training sequence
    fps: float
    joints: tuple[str, ...]
    rotation: str
    audio_dim: int
    past: int  # audio frames before the current one in the control window
    lookahead: int  # audio frames after it
    sample_rate: int | None = None  # of the takes' audio, where they share one (what a stream must send)


@dataclass
class NeutralPose:
    """The pose of everything the model does not generate: all local rotations and the root position."""

    rotations: np.ndarray  # (J, 3, 3) of the full skeleton
    root: np.ndarray  # (3,)

    @classmethod
    def of(cls, motions: list[Motion]) -> NeutralPose:
        """Chordal mean rotation of every joint (the rotation nearest the mean matrix) and mean root."""
        rotations = np.concatenate([m.rotations for m in motions]).mean(axis=0)
        mean = roma.special_procrustes(torch.tensor(rotations)).numpy()
        root = np.concatenate([m.root_positions for m in motions]).mean(axis=0)
        return cls(mean, root)

    def to_dict(self) -> dict:
        return {"rotations": self.rotations.tolist(), "root": self.root.tolist()}

    @classmethod
    def from_dict(cls, data: dict) -> NeutralPose:
        return cls(
            np.asarray(data["rotations"], dtype=np.float64), np.asarray(data["root"], dtype=np.float64)
        )
