"""walkdiff: diffusion-based human motion synthesis with Lightning and MLflow.

The Python API (docs/api.md) is reached from here, each name imported on first use, so that `import
walkdiff` or `import walkdiff.common.errors` stays light (no torch) until a model is asked for.
"""

from importlib import import_module

__version__ = "0.1.0"

# Public name -> the module that defines it.
_API = {
    "load": "walkdiff.api",
    "StyledGenerator": "walkdiff.styled.pipeline",
    "PathFollower": "walkdiff.walker.follow",
    "GestureGenerator": "walkdiff.gestures.generator",
    "Generated": "walkdiff.models.pipeline",
    "Style": "walkdiff.models.style_spec",
    "SamplerChoice": "walkdiff.diffusion.samplers",
    "Take": "walkdiff.motion.take",
    "TargetRig": "walkdiff.motion.target_rig",
    "Motion": "walkdiff.motion.skeleton",
    "read_bvh": "walkdiff.motion.bvh",
    "WalkdiffError": "walkdiff.common.errors",
}
__all__ = list(_API)


def __getattr__(name: str):
    if name not in _API:
        raise AttributeError(f"module 'walkdiff' has no attribute {name!r}")
    value = getattr(import_module(_API[name]), name)
    globals()[name] = value  # found directly from now on
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_API))
