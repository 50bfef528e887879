"""Distribution metrics on evaluator features: Fréchet motion distance, diversity, multimodality.

The metrics take feature tensors (B, D), never motions, so that any evaluator (the action recogniser of
Action2Motion/ACTOR, a style classifier on Xia, ...) can feed them. Random pairs are drawn from a generator
seeded at every ``compute``: after a DDP sync all ranks hold the same samples in the same order, so all ranks
draw the same pairs and report the same value.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import Tensor, nn
from torchmetrics import Metric
from torchmetrics.image.fid import FrechetInceptionDistance, _compute_fid
from torchmetrics.utilities import dim_zero_cat

from walkdiff.common.errors import WalkdiffError


def frechet_distance(
    mu1: Tensor | np.ndarray,
    sigma1: Tensor | np.ndarray,
    mu2: Tensor | np.ndarray,
    sigma2: Tensor | np.ndarray,
) -> Tensor:
    """Fréchet distance ||mu1 - mu2||^2 + Tr(S1 + S2 - 2 (S1 S2)^(1/2)) between two Gaussians, in float64."""
    mu1, sigma1, mu2, sigma2 = (torch.as_tensor(a, dtype=torch.float64) for a in (mu1, sigma1, mu2, sigma2))
    d = mu1.numel()
    if mu1.shape != (d,) or mu2.shape != (d,) or sigma1.shape != (d, d) or sigma2.shape != (d, d):
        raise WalkdiffError(
            f"frechet_distance expects means (D,) and covariances (D, D) of one size D, got "
            f"{tuple(mu1.shape)}, {tuple(sigma1.shape)}, {tuple(mu2.shape)}, {tuple(sigma2.shape)}"
        )
    return _compute_fid(mu1, sigma1, mu2, sigma2)


class _GivenFeatures(nn.Identity):
    """Stands in for FID's feature network: the inputs already are evaluator features (B, num_features)."""

    def __init__(self, num_features: int):
        super().__init__()
        self.num_features = num_features


class FrechetMotionDistance(FrechetInceptionDistance):
    """FID on motion-evaluator features: ``update(features (B, D), real: bool)``, then ``compute()``.

    torchmetrics' FID accepts any ``nn.Module`` with a ``num_features`` attribute as its feature network and
    then never builds a dummy image, so an identity module makes it a metric on given features. It already
    keeps the states this protocol needs: float64 sums, sums of outer products and counts, all reduced by
    'sum' across DDP ranks. ``reset_real_features=False`` keeps the real statistics across resets, so a
    training callback extracts the real set once.
    """

    def __init__(self, num_features: int, reset_real_features: bool = True, **kwargs: Any):
        if num_features < 1:
            raise WalkdiffError(f"FrechetMotionDistance needs num_features >= 1, got {num_features}")
        super().__init__(
            feature=_GivenFeatures(num_features), reset_real_features=reset_real_features, **kwargs
        )
        # FID sets this in update(); a DDP rank that saw no batch would otherwise fail in compute().
        self.orig_dtype = torch.float32

    def update(self, features: Tensor, real: bool) -> None:
        """Add a batch of real or generated evaluator features (B, D)."""
        d = self.inception.num_features
        if features.ndim != 2 or features.shape[1] != d:
            raise WalkdiffError(
                f"FrechetMotionDistance expects features (B, {d}), got {tuple(features.shape)}"
            )
        super().update(features, real)


def random_pairs(n: int, num_pairs: int, generator: torch.Generator) -> tuple[Tensor, Tensor]:
    """Indices of ``num_pairs`` random pairs of two different samples out of ``n``, drawn with replacement."""
    first = torch.randint(n, (num_pairs,), generator=generator)
    # An offset in [1, n) makes the partner uniform over the other n - 1 samples: never a sample with itself.
    second = (first + torch.randint(1, n, (num_pairs,), generator=generator)) % n
    return first, second


def _check_pairs_args(name: str, num_pairs: int) -> None:
    if num_pairs < 1:
        raise WalkdiffError(f"{name} needs num_pairs >= 1, got {num_pairs}")


class Diversity(Metric):
    """Mean L2 distance between the features of ``num_pairs`` random pairs of samples (ACTOR/MDM diversity).

    Compare the value on generated features with the value on real features: the closer, the better.
    """

    is_differentiable = False
    higher_is_better = None
    full_state_update = False

    def __init__(self, num_pairs: int = 200, seed: int = 0, **kwargs: Any):
        super().__init__(**kwargs)
        _check_pairs_args("Diversity", num_pairs)
        self.num_pairs = num_pairs
        self.seed = seed
        self.add_state("features", default=[], dist_reduce_fx="cat")

    def update(self, features: Tensor) -> None:
        """Add a batch of evaluator features (B, D)."""
        if features.ndim != 2:
            raise WalkdiffError(f"Diversity expects features (B, D), got {tuple(features.shape)}")
        self.features.append(features)

    def compute(self) -> Tensor:
        features = dim_zero_cat(self.features).double()
        if len(features) < 2:
            raise WalkdiffError(f"Diversity needs at least 2 samples, got {len(features)}")
        generator = torch.Generator().manual_seed(self.seed)
        first, second = random_pairs(len(features), self.num_pairs, generator)
        return (features[first] - features[second]).norm(dim=1).mean()


class Multimodality(Metric):
    """Per class, mean L2 distance over ``num_pairs`` random pairs of same-label samples; mean over classes.

    As in Action2Motion/ACTOR, on generated features with their conditioning labels. Classes with fewer than
    two samples have no pair and are left out of the mean.
    """

    is_differentiable = False
    higher_is_better = None
    full_state_update = False

    def __init__(self, num_pairs: int = 20, seed: int = 0, **kwargs: Any):
        super().__init__(**kwargs)
        _check_pairs_args("Multimodality", num_pairs)
        self.num_pairs = num_pairs
        self.seed = seed
        self.add_state("features", default=[], dist_reduce_fx="cat")
        self.add_state("labels", default=[], dist_reduce_fx="cat")

    def update(self, features: Tensor, labels: Tensor) -> None:
        """Add a batch of evaluator features (B, D) with their integer class labels (B,)."""
        if features.ndim != 2 or labels.shape != features.shape[:1]:
            raise WalkdiffError(
                "Multimodality expects features (B, D) and labels (B,), got "
                f"{tuple(features.shape)} and {tuple(labels.shape)}"
            )
        self.features.append(features)
        self.labels.append(labels.long())

    def compute(self) -> Tensor:
        features = dim_zero_cat(self.features).double()
        labels = dim_zero_cat(self.labels)
        generator = torch.Generator().manual_seed(self.seed)
        per_class = []
        for label in labels.unique(sorted=True):
            members = features[labels == label]
            if len(members) < 2:
                continue
            first, second = random_pairs(len(members), self.num_pairs, generator)
            per_class.append((members[first] - members[second]).norm(dim=1).mean())
        if not per_class:
            raise WalkdiffError("Multimodality needs a class with at least 2 samples, got none")
        return torch.stack(per_class).mean()
