"""What every walkdiff LightningModule shares: its data spec, normaliser and skeleton profile, kept in
checkpoints."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import lightning as L

from walkdiff.common.errors import WalkdiffError
from walkdiff.models.body_terms import BodyTerms
from walkdiff.motion.profile import SkeletonProfile
from walkdiff.motion.representation import FeatureLayout, Normalizer
from walkdiff.motion.skeleton import Motion, Skeleton
from walkdiff.spec import DataSpec


class MotionModule(L.LightningModule):
    """Base of the models: a checkpoint alone is enough to decode, export and score their motion.

    The data spec (feature width, joints, labels) arrives from the data module through the CLI link and
    is saved as a plain dict in the hyperparameters; the normaliser is copied from the data module when
    training starts and lives in the state dict; the skeleton profile (the file's skeleton, root, feet,
    axes, units) is stored in the checkpoint, so no command needs the dataset's code to use it.
    """

    def __init__(self, data_spec: DataSpec | dict | None):
        super().__init__()
        if data_spec is None:
            raise WalkdiffError(
                "model.data_spec is missing: it is linked from the data module by `walkdiff fit`"
            )
        self.spec = data_spec if isinstance(data_spec, dict) else asdict(data_spec)
        self.layout = FeatureLayout(self.spec["num_joints"])
        self.normalizer = Normalizer(self.spec["feature_dim"])
        self.profile: SkeletonProfile | None = None

    @property
    def skeleton(self) -> Skeleton | None:
        """The canonical skeleton the model's features are on (None before training starts)."""
        return None if self.profile is None else self.profile.canonical_skeleton

    @property
    def body_terms(self) -> BodyTerms:
        """The world-position training terms' forward kinematics and units on the model's skeleton
        (`BodyTerms`), made once per skeleton profile."""
        if getattr(self, "_body_terms", None) is None or self._body_terms.profile is not self.profile:
            self._body_terms = BodyTerms(self.profile, self.spec["fps"])
        return self._body_terms

    def to_file(self, motion: Motion) -> Motion:
        """A canonical clip on the training files' skeleton, axes and root layout, ready to write."""
        return self.profile.to_file(motion)

    def setup(self, stage: str) -> None:
        datamodule = getattr(self.trainer, "datamodule", None) if self._trainer is not None else None
        if datamodule is None:
            return
        datamodule.setup(stage)
        if stage == "fit":  # a resumed run then loads the same statistics back from its checkpoint
            self.normalizer.load_state_dict(datamodule.normalizer.state_dict())
        if self.profile is None:
            self.profile = datamodule.profile

    @classmethod
    def from_trained(cls, path: str | Path, what: str, device="cpu"):
        """A trained model for generation or scoring, with clear errors for a missing or wrong file.

        `what` names the model in messages (e.g. "generator").
        """
        import torch

        from walkdiff.common.checkpoints import expect_class, loadable

        if str(device).startswith("cuda") and not torch.cuda.is_available():
            raise WalkdiffError(f"--device {device}: this torch build sees no CUDA GPU; use --device cpu")
        path = Path(path)
        expect_class(path, f"{cls.__module__}.{cls.__qualname__}", what)
        try:
            model = cls.load_from_checkpoint(loadable(path), map_location="cpu", weights_only=True)
        except (KeyError, RuntimeError, TypeError) as error:
            raise WalkdiffError(
                f"not a {what} checkpoint ({type(error).__name__}: {error})", path=path
            ) from None
        except WalkdiffError as error:  # raised while loading, before the file was known
            raise WalkdiffError(error.reason, path=error.path or path, line=error.line) from None
        if model.profile is None:
            raise WalkdiffError(
                f"the {what} checkpoint has no skeleton profile; was it saved by `walkdiff fit` of this "
                "walkdiff version?",
                path=path,
            )
        return model.to(device).eval()

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        # Which model this is, for commands that take any checkpoint (`walkdiff evaluate`).
        checkpoint["model_class"] = f"{type(self).__module__}.{type(self).__qualname__}"
        if self.profile is not None:
            checkpoint["skeleton_profile"] = self.profile.to_dict()

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        if "skeleton_profile" in checkpoint:
            self.profile = SkeletonProfile.from_dict(checkpoint["skeleton_profile"])
