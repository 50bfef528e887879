"""Run by Blender's Python (`blender --background --python tests/blender_import.py -- FILES`, or a Python
with the `bpy` module: `python tests/blender_import.py FILES`): import each BVH or .glb as Blender's own
importers do and print, as one JSON line per file, the armature's bones and the world positions of their
heads at 0 s and 1 s. `tests/test_blender.py` compares them with walkdiff's own forward kinematics."""

import json
import sys

import bpy

TIMES = (0.0, 1.0)


def positions(armature, scene, fps: float, start: float) -> list[dict[str, list[float]]]:
    rows = []
    for seconds in TIMES:
        scene.frame_set(round(start + seconds * fps))
        rows.append({b.name: list(armature.matrix_world @ b.head) for b in armature.pose.bones})
    return rows


def main(paths: list[str]) -> None:
    for path in paths:
        bpy.ops.wm.read_factory_settings(use_empty=True)
        scene = bpy.context.scene
        if path.lower().endswith(".bvh"):
            bpy.ops.import_anim.bvh(filepath=path, update_scene_fps=True, update_scene_duration=True)
        else:
            bpy.ops.import_scene.gltf(filepath=path)
        fps = scene.render.fps / scene.render.fps_base
        armatures = [o for o in bpy.data.objects if o.type == "ARMATURE"]
        row = {"file": path, "armatures": len(armatures), "fps": fps, "actions": len(bpy.data.actions)}
        if armatures:
            row["bones"] = [b.name for b in armatures[0].data.bones]
            start = bpy.data.actions[0].frame_range[0]  # the clip's first frame (0 s)
            row["positions"] = positions(armatures[0], scene, fps, start)
        print("BLENDER " + json.dumps(row), flush=True)


if __name__ == "__main__":
    args = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else sys.argv[1:]
    main(args)
