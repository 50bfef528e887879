"""Where real planted feet stand, kept in a generator's checkpoint so its motion can be grounded.

A generated clip whose body floats or sinks a few centimetres looks the same, but its swinging feet then
pass under the contact height and count as sliding. The heights are measured once, on the training clips
when training starts, and generated motion is shifted vertically onto them (`walkdiff.motion.footfix`):
a whole clip at once (`ground`), or a frame at a time as it is made (`running_ground`).
"""

from __future__ import annotations

import logging

import numpy as np
import torch

from walkdiff.common.errors import WalkdiffError
from walkdiff.motion.footfix import RunningGround, ground, planted_heights

log = logging.getLogger(__name__)

# How fast a frame-by-frame ground shift may settle: contact heights (0.0326 leg lengths) a second.
SETTLE_HEIGHTS_PER_SECOND = 4.0


class PlantedFeet:
    """Mixin of a `MotionModule`: the `planted_height` buffer, measured at fit, used to ground motion."""

    def init_planted_feet(self) -> None:
        # Measured on the unmirrored training clips: a mirrored copy keeps Xia's asymmetric offsets, so
        # its feet stand up to ~0.2 units off where a real foot on that side does.
        self.register_buffer("planted_height", torch.zeros(4))
        self.grounded_heights = True

    @property
    def contact_spec(self):
        return self.profile.contacts

    def measure_planted_feet(self, datamodule) -> None:
        train = [f for _, _, f in datamodule.split_features("train")]
        heights = planted_heights(train, self.skeleton, self.contact_spec)
        never = [n for n, h in zip(self.contact_spec.joints, heights, strict=True) if np.isnan(h)]
        if never:
            log.warning(f"contact joints never planted in the training data: {', '.join(never)}; "
                        "grounding of generated motion leaves them out")  # fmt: skip
        self.planted_height.copy_(torch.from_numpy(heights))

    def load_planted_feet(self, checkpoint: dict) -> None:
        """Checkpoints saved before walkdiff measured planted feet load, but cannot be grounded."""
        self.grounded_heights = "planted_height" in checkpoint["state_dict"]
        checkpoint["state_dict"].setdefault("planted_height", torch.full((4,), float("nan")))

    def ground(self, raw: np.ndarray) -> np.ndarray:
        """Raw features (..., F, D) shifted so their planted feet stand where real ones do."""
        if not self.grounded_heights:
            raise WalkdiffError(
                "this checkpoint was saved before walkdiff stored where planted feet stand, so its clips "
                "cannot be grounded: retrain it, or pass --no-ground"
            )
        return ground(raw, self.skeleton, self.contact_spec, self.planted_height.cpu().numpy())

    def running_ground(self, rows: int) -> RunningGround:
        """Grounding for `rows` streams made a frame at a time (each frame: (rows, D) -> grounded)."""
        if not self.grounded_heights:
            log.warning("this checkpoint was saved before walkdiff stored where planted feet stand: its "
                        "frames are not grounded (retrain it to ground them)")  # fmt: skip
        rate = SETTLE_HEIGHTS_PER_SECOND * self.contact_spec.height_threshold / self.spec["fps"]
        return RunningGround(self.skeleton, self.contact_spec, self.planted_height.cpu().numpy(), rows, rate)
