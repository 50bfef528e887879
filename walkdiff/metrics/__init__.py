"""Evaluation metrics as torchmetrics ``Metric`` classes, so they sync across DDP ranks.

Protocol of Action2Motion / ACTOR / MDM adapted to the Xia style database: an evaluator turns motions into
features (B, D) and class logits; the metrics here take those tensors, not motions.

- ``FrechetMotionDistance``, ``Diversity``, ``Multimodality`` (distribution.py) and ``frechet_distance``;
- ``FootSkating``, ``Jitter`` (physics.py) on world joint positions;
- ``summarize``, ``summarize_runs``, ``format_summary`` (protocol.py): mean ± 1.96·σ/√n over repetitions.

Recognition accuracy needs no class of its own: use torchmetrics directly on the evaluator's logits,
``MulticlassAccuracy(num_classes, average="micro")`` (share of correctly recognised samples, as reported in
the papers) and ``MulticlassConfusionMatrix(num_classes, normalize="true")`` for per-class recall rows.
"""

from walkdiff.metrics.distribution import Diversity, FrechetMotionDistance, Multimodality, frechet_distance
from walkdiff.metrics.physics import FootSkating, Jitter
from walkdiff.metrics.protocol import format_summary, summarize, summarize_runs

__all__ = [
    "Diversity",
    "FootSkating",
    "FrechetMotionDistance",
    "Jitter",
    "Multimodality",
    "format_summary",
    "frechet_distance",
    "summarize",
    "summarize_runs",
]
