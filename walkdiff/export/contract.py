"""The JSON beside an exported frame: everything an engine needs to run it without reading walkdiff's
Python. docs/game-engines.md walks through it; `docs/onnx_loop.py` follows it with numpy alone, and a
test holds that loop to walkdiff's own frames."""

from __future__ import annotations

import numpy as np

from walkdiff.diffusion import SamplerChoice
from walkdiff.export.graphs import frame_graph, frame_kind

FORMAT = "walkdiff-onnx-frame/1"

SIXD = (
    "6 numbers (a1, a2) per joint, the first two columns of its rotation matrix before Gram-Schmidt: "
    "b1 = a1 / |a1|, b2 = (a2 - (b1.a2) b1) / |...|, b3 = b1 x b2, R = [b1 b2 b3] (columns)"
)
EXPMAP = "3 numbers per joint: a rotation vector (axis times angle in radians), R = exp([v]x)"


def contract(model, sampler: SamplerChoice, onnx_name: str) -> dict:
    """The contract of `model`'s frame under `sampler`, its graph in the file `onnx_name`."""
    kind = frame_kind(model)
    graph = frame_graph(model, sampler)
    steps, spec, lstm = graph.steps, model.spec, model.encoder.lstm
    dim, layers, hidden = spec["feature_dim"], lstm.num_layers, lstm.hidden_size
    state = [
        _io("previous", ["batch", dim], "the pose of the frame before, normalised (previous_out of the last "
            "frame; zeros, the mean pose, at a start)"),
        _io("h", [layers, "batch", hidden], "the LSTM's hidden state (h_out of the last frame; zeros at "
            "a start)"),
        _io("c", [layers, "batch", hidden], "the LSTM's cell state (c_out of the last frame; zeros at a "
            "start)"),
        _io("noise", [graph.noise_slots, "batch", dim], "fresh standard normal float32 noise every frame: "
            "slot 0 starts the sampler, slot k + 1 is added after step k (only the slots in "
            "noise.used matter; the others may be anything)"),
    ]  # fmt: skip
    outputs = [
        _io("pose", ["batch", dim], "the frame's pose features in the model's units (see features)"),
        _io("previous_out", ["batch", dim], "feed back as previous"),
        _io("h_out", [layers, "batch", hidden], "feed back as h"),
        _io("c_out", [layers, "batch", hidden], "feed back as c"),
    ]
    terms = {
        "format": FORMAT,
        "kind": kind,
        "onnx": onnx_name,
        "opset": 17,
        "model_class": f"{type(model).__module__}.{type(model).__qualname__}",
        "fps": float(spec["fps"]),
        "batch": "the 'batch' axis is free: one row per character or stream, all run in one call; every "
        "other axis is fixed",
        "sampler": {
            "label": sampler.label(model.diffusion),
            **sampler.record(),
            "timesteps": steps.timesteps,
            "sigma": steps.sigma,
        },
        "noise": {
            "shape": [graph.noise_slots, "batch", dim],
            "distribution": "standard normal N(0, 1), float32, drawn anew every frame",
            "used": [0] + [k + 1 for k, s in enumerate(steps.sigma) if s > 0],
        },
        "inputs": (_walker_inputs(model) if kind == "walker" else _gesture_inputs(model)) + state,
        "outputs": outputs,
        "loop": "start: previous, h, c zero for every row; each frame: run the graph, read pose, then feed "
        "previous_out, h_out and c_out back as previous, h and c of the next frame",
        "normalizers": _normalizers(model, kind),
        "skeleton": _skeleton(model),
    }
    terms |= _walker_terms(model) if kind == "walker" else _gesture_terms(model)
    return terms


def _io(name: str, shape: list, meaning: str) -> dict:
    return {"name": name, "shape": shape, "dtype": "float32", "meaning": meaning}


def _walker_inputs(model) -> list[dict]:
    k, styles = len(model.ahead), list(model.spec["styles"])
    return [
        _io("control", ["batch", 2 * k], f"where to walk: {k} points (x, z) on the walker's path, "
            "control.ahead_frames frames ahead, in the walker's own frame (z forward, x "
            "sideways: see control.frame) and the skeleton's units; interleaved x0, z0, x1, z1, .."),
        _io("style", ["batch", len(styles)], f"mixing weights over the styles {styles}, >= 0, summing to 1"),
    ]  # fmt: skip


def _gesture_inputs(model) -> list[dict]:
    spec = model.spec
    return [
        _io("audio", ["batch", model.window, spec["audio_dim"]], f"log-mel frames (see audio) from "
            f"{spec['past']} frames before the pose's frame to {spec['lookahead']} after it; before the "
            "first frame and after the last, the edge frame repeated"),
    ]  # fmt: skip


def _normalizers(model, kind: str) -> dict:
    """The statistics the graph applies inside (listed for reference: the engine applies none)."""

    def stats(normalizer) -> dict:
        return {"mean": _floats(normalizer.mean), "std": _floats(normalizer.std)}

    out = {
        "applied": "inside the graph: feed raw inputs, read raw pose features",
        "pose": stats(model.normalizer),
    }
    out["control" if kind == "walker" else "audio"] = stats(
        model.control_normalizer if kind == "walker" else model.audio_normalizer
    )
    return out


def _skeleton(model) -> dict:
    """The canonical skeleton the features are on (walkdiff's axes: Y up, a walker faces +Z)."""
    profile, skeleton = model.profile, model.skeleton
    return {
        "axes": "Y up; heading 0 faces +Z, heading 90 degrees faces +X",
        "names": list(skeleton.names),
        "parents": [int(p) for p in skeleton.parents],
        "offsets": np.round(skeleton.offsets, 6).tolist(),
        "rotation_order": [skeleton.rotation_order(j) for j in range(skeleton.num_joints)],
        "root": skeleton.names[0],
        "units": profile.units,
        "metres_per_unit": profile.metres_per_unit,
        "to_file_axes": np.round(profile.turn.T, 9).tolist(),
        "rotations": "local to the parent, as matrices R acting on column vectors: world_j = world_parent "
        "R_j, position_j = position_parent + world_parent offset_j; the file's axes are "
        "to_file_axes times these (offsets and positions alike), its Euler channels in rotation_order",
    }


def _walker_terms(model) -> dict:
    layout, spec = model.layout, model.spec
    joints = layout.num_joints
    return {
        "control": {
            "ahead_frames": list(model.ahead),
            "frame": "a world point (X, Z) seen from a walker at (x0, z0) facing heading h (radians, 0: +Z, "
            "pi/2: +X): dx = X - x0, dz = Z - z0, x = dx cos h - dz sin h, z = dx sin h + dz cos h",
            "straight": "to walk at speed v (units per second) in direction d (radians, world), point k is "
            "v t_k (sin(d - h), cos(d - h)) with t_k = ahead_frames[k] / fps (aim at most 90 degrees off the "
            "heading: walkdiff's controller bends the points along an arc at up to 720 degrees/s, then "
            "straight on); speed 0 puts every point at (0, 0): the walker stops",
            "style_speed": {
                s: float(v) for s, v in zip(spec["styles"], model.style_speed.tolist(), strict=True)
            },
            "style_speed_units": "the style's mean walking speed in the training data, units per second "
            "(a default pace; 0: unknown)",
        },
        "features": {
            "layout": {
                "root_velocity": [0, 2],
                "root_height": [2, 3],
                "heading_velocity": [3, 4],
                "rotations": [layout.rotations.start, layout.rotations.stop],
                "contacts": [layout.contacts.start, layout.contacts.stop],
            },
            "root_velocity": "(vx, vz): the root's move over the frame in the walker's own frame (units)",
            "root_height": "the root's height above the floor (units)",
            "heading_velocity": "the turn over the frame (radians, added after the frame)",
            "rotations": f"{joints} joints in skeleton order, " + SIXD + "; the root's is relative to the "
            "heading: its world rotation is Yaw(h) R_root",
            "contacts": "left heel, left toe, right heel, right toe on the ground (> 0.5) in this frame",
        },
        "pose_to_world": "keep the root (x, z) and heading h, start (0, 0) and 0 (or where the character "
        "stands); each frame: root position = (x, root_height, z), root rotation = Yaw(h) R_root with "
        "Yaw(h) = [[cos h, 0, sin h], [0, 1, 0], [-sin h, 0, cos h]], the other joints their rotations and "
        "offsets; then x += vx cos h + vz sin h, z += -vx sin h + vz cos h, h += heading_velocity",
    }


def _gesture_terms(model) -> dict:
    from walkdiff.data.speech import LOG_FLOOR, frame_aligned_rate

    spec, neutral, skeleton = model.spec, model.neutral, model.skeleton
    rate = spec.get("sample_rate")
    hop = None if rate is None else int(frame_aligned_rate(rate, spec["fps"]) / spec["fps"])
    return {
        "audio": {
            "sample_rate": rate,
            "features": "natural log of (mel power + 1e-10) per motion frame, frame k centred at k / fps",
            "hop_length": hop,
            "win_length": None if hop is None else 2 * hop,
            "n_fft": None if hop is None else 1 << (2 * hop - 1).bit_length(),
            "n_mels": spec["audio_dim"],
            "power": 2.0,
            "log_floor": LOG_FLOOR,
            "mel_filters": "Slaney-style mel scale and area normalisation (librosa's defaults), Hann "
            "window, frames centred with reflect padding",
            "past": spec["past"],
            "lookahead": spec["lookahead"],
        },  # fmt: skip
        "features": {
            "joints": list(spec["joints"]),
            "rotation": spec["rotation"],
            "layout": f"{len(spec['joints'])} joints in that order, "
            + (SIXD if spec["rotation"] == "6d" else EXPMAP),
        },
        "neutral_pose": {
            "rotations": np.round(neutral.rotations, 9).tolist(),
            "root": np.round(neutral.root, 6).tolist(),
            "meaning": "every joint not in features.joints keeps these local rotations (skeleton order); the "
            "root stands at root",
        },
        "pose_to_world": "the joints of features.joints take the frame's rotations, every other joint its "
        "neutral_pose rotation, the root its neutral_pose position",
        "skeleton_joints_modelled": [skeleton.index(n) for n in spec["joints"]],
    }


def _floats(values) -> list[float]:
    return [float(v) for v in values.detach().cpu().tolist()]
