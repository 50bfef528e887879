"""HumanAct12 on the SMPL skeleton, without the real file: small pkl files with the exact schema of
humanact12poses.pkl (smooth random SMPL poses and the joints SMPL's FK gives them) go through loading,
windowing, the feature round trip, BVH export, a few training steps and the errors for bad files."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import lightning as L
import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from walkdiff.callbacks.samples import SampleClips
from walkdiff.cli.main import main
from walkdiff.common.errors import WalkdiffError
from walkdiff.data import humanact12
from walkdiff.data.clips import ContentSelection
from walkdiff.data.datamodule import MotionDataModule
from walkdiff.evaluation.scorer import load_evaluator
from walkdiff.models.action_evaluator import ActionEvaluator
from walkdiff.models.styled_ddpm import StyledMotionDiffusion
from walkdiff.motion.bvh import read_bvh, write_bvh
from walkdiff.motion.kinematics import motion_world_positions
from walkdiff.motion.profile import SkeletonProfile
from walkdiff.motion.representation import decode, encode, start_pose
from walkdiff.motion.smpl import BVH_ORDER, NAMES, SMPL_PARENTS

# A plausible SMPL rest skeleton (metres, Y-up, facing +Z, left = +X): each joint's offset from its parent.
REST = np.array([
    [0.0, 0.0, 0.0], [0.06, -0.09, 0.0], [-0.06, -0.09, 0.0], [0.0, 0.11, -0.02], [0.04, -0.38, 0.0],
    [-0.04, -0.38, 0.0], [0.0, 0.13, 0.01], [-0.01, -0.40, -0.04], [0.01, -0.40, -0.04], [0.0, 0.05, 0.0],
    [0.02, -0.06, 0.12], [-0.02, -0.06, 0.12], [0.0, 0.21, -0.03], [0.07, 0.11, -0.01], [-0.07, 0.11, -0.01],
    [0.0, 0.09, 0.05], [0.11, 0.04, -0.01], [-0.11, 0.04, -0.01], [0.26, 0.0, -0.02], [-0.26, 0.0, -0.02],
    [0.25, 0.01, 0.0], [-0.25, 0.01, 0.0], [0.08, -0.01, -0.01], [-0.08, -0.01, -0.01],
])  # fmt: skip
CONF = Path(__file__).resolve().parents[1] / "conf"
# The file's axes in the tests: Y down (a camera's), as SMPL fits to video often are.
Y_DOWN = np.diag([1.0, -1.0, -1.0])


def smpl_fk(rotvecs: np.ndarray, root: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """(T, 24, 3) joints from (T, 24, 3) axis-angle and (T, 3) pelvis positions: SMPL's kinematic chain."""
    local = Rotation.from_rotvec(rotvecs.reshape(-1, 3)).as_matrix().reshape(*rotvecs.shape[:2], 3, 3)
    world = np.zeros_like(local)
    joints = np.zeros(rotvecs.shape)
    world[:, 0], joints[:, 0] = local[:, 0], root
    for j in range(1, 24):
        p = SMPL_PARENTS[j]
        world[:, j] = world[:, p] @ local[:, j]
        joints[:, j] = joints[:, p] + world[:, p] @ rest[j]
    return joints


def random_clip(rng: np.random.Generator, frames: int, to_file: np.ndarray = Y_DOWN):
    """Smooth random SMPL poses (a few sinusoids per angle), a moving pelvis, and their joints."""
    t = np.arange(frames)[:, None, None] / humanact12.FPS
    freq = rng.uniform(0.2, 1.5, (3, 24, 3))
    amp = rng.uniform(0.0, 0.4, (3, 24, 3))
    phase = rng.uniform(0, 2 * np.pi, (3, 24, 3))
    rotvecs = sum(amp[k] * np.sin(2 * np.pi * freq[k] * t + phase[k]) for k in range(3))
    heading = rng.uniform(-np.pi, np.pi) + 0.3 * np.sin(t[:, 0, 0])
    root_rot = Rotation.from_rotvec(heading[:, None] * [0, 1, 0]) * Rotation.from_rotvec(rotvecs[:, 0] * 0.3)
    # The file stores the pose in its own axes: its root rotation and positions are turned by to_file.
    rotvecs[:, 0] = (Rotation.from_matrix(to_file) * root_rot).as_rotvec()
    walk = np.cumsum(rng.normal(0, 0.02, (frames, 3)), axis=0) + [0.0, 0.9, 0.0]
    joints = smpl_fk(rotvecs, walk @ to_file.T, REST * rng.uniform(0.9, 1.1))
    return rotvecs.reshape(frames, 72).astype(np.float32), joints.astype(np.float32)


def write_pkl(path: Path, per_action: int = 2, frames=(70, 90), seed: int = 0) -> Path:
    rng = np.random.default_rng(seed)
    data = {"poses": [], "joints3D": [], "y": []}
    for action in range(len(humanact12.GROUPS)):
        for _ in range(per_action):
            poses, joints = random_clip(rng, int(rng.integers(*frames)))
            data["poses"].append(poses)
            data["joints3D"].append(joints)
            data["y"].append(action)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(pickle.dumps(data))
    return path


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("humanact12")
    write_pkl(root / "humanact12" / humanact12.FILE_NAME)
    return root


@pytest.fixture(scope="module")
def datamodule(root) -> MotionDataModule:
    dm = MotionDataModule(
        dataset="humanact12", root=str(root), contents="all", fps=20.0, window=60, stride=10, mirror=False,
        batch_size=8, cache_dir=str(root / "cache"), preprocess_workers=1,
    )  # fmt: skip
    dm.setup("fit")
    return dm


def pkl_path(root: Path) -> Path:
    return root / "humanact12" / humanact12.FILE_NAME


# ---------------------------------------------------------------- loading


def test_smpl_tree_in_depth_first_order():
    assert sorted(BVH_ORDER) == list(range(24)) and BVH_ORDER[0] == 0
    position = {smpl: k for k, smpl in enumerate(BVH_ORDER)}
    for k, smpl in enumerate(BVH_ORDER[1:], start=1):
        assert position[SMPL_PARENTS[smpl]] < k  # parents precede children
    # Depth first: each joint's subtree is a contiguous run right after it (left leg whole, then right).
    assert NAMES[:5] == ["pelvis", "left_hip", "left_knee", "left_ankle", "left_foot"]


def test_list_clips_and_splits(root):
    clips = humanact12.list_clips(root / "humanact12")
    assert len(clips) == 24 and [c.item for c in clips] == list(range(24))
    assert clips[5].name == "humanact12_0005" and clips[5].content == 2 and clips[5].style == 0
    selection = ContentSelection.parse("all", humanact12.GROUPS)
    splits = humanact12.split_clips(clips, selection)
    assert len(splits["val"]) == 12 and len(splits["train"]) == 12  # one of each action's two clips
    assert {c.name for c in splits["test"]} == {c.name for c in clips}
    assert not {c.name for c in splits["val"]} & {c.name for c in splits["train"]}
    walk = humanact12.split_clips(clips, ContentSelection.parse("walk,run", humanact12.GROUPS))
    assert {c.content for c in walk["test"]} == {1, 2} and len(walk["train"]) == 2


def test_loaded_clip_reproduces_joints3D_in_y_up(root):
    path = pkl_path(root)
    data = pickle.loads(path.read_bytes())
    assert humanact12.read_pkl(path).up == "-y"
    for item in (0, 13):
        motion = humanact12.load_clip(path, item)
        assert motion.fps == 20 and motion.skeleton.names == NAMES
        expected = data["joints3D"][item].astype(np.float64)[:, BVH_ORDER] @ Y_DOWN.T
        expected[..., 1] -= expected[..., 1].min()
        positions = motion_world_positions(motion)
        assert np.abs(positions - expected).max() < 1e-5  # float32 file, float64 FK
        head, pelvis = NAMES.index("head"), NAMES.index("pelvis")
        assert (positions[:, head, 1] > positions[:, pelvis, 1]).all()  # Y is up now
        assert positions[..., 1].min() == pytest.approx(0.0, abs=1e-6)  # on the floor
    # Naming the wrong up axis keeps the rigid motion but leaves the figure upside down.
    flipped = motion_world_positions(humanact12.load_clip(path, 0, up="+y"))
    assert (flipped[:, NAMES.index("head"), 1] < flipped[:, 0, 1]).all()


@pytest.mark.parametrize("up", ["+y", "-y", "+z", "-z", "+x", "-x"])
def test_any_up_axis_of_the_file_is_found_and_turned_to_y(tmp_path, up):
    rng = np.random.default_rng(1)
    to_file = humanact12.UP_ROTATIONS[up].T  # walkdiff's +Y becomes the file's `up`
    clips = [random_clip(rng, 20, to_file) for _ in range(2)]
    path = tmp_path / humanact12.FILE_NAME
    path.write_bytes(
        pickle.dumps({"poses": [c[0] for c in clips], "joints3D": [c[1] for c in clips], "y": [0, 5]})
    )
    assert humanact12.read_pkl(path).up == up
    positions = motion_world_positions(humanact12.load_clip(path, 1))
    assert (positions[:, NAMES.index("head"), 1] > positions[:, NAMES.index("pelvis"), 1] + 0.3).all()


# ---------------------------------------------------------------- features, windows, BVH


def test_feature_round_trip_and_bvh_export(root, tmp_path):
    worst_decode = worst_bvh = 0.0
    for item in (0, 7, 22):
        motion = humanact12.load_clip(pkl_path(root), item)
        positions = motion_world_positions(motion)
        profile = SkeletonProfile.detect(motion, humanact12.PROFILE)
        features = encode(motion, profile)
        assert features.shape == (motion.num_frames, 8 + 6 * 24)
        position, heading = start_pose(motion, profile)
        decoded = decode(features, motion.skeleton, motion.frame_time, position, heading)
        worst_decode = max(worst_decode, np.abs(motion_world_positions(decoded) - positions).max())

        write_bvh(tmp_path / f"{item}.bvh", motion)
        back = read_bvh(tmp_path / f"{item}.bvh")
        assert back.skeleton.names == NAMES and np.array_equal(back.skeleton.parents, motion.skeleton.parents)
        worst_bvh = max(worst_bvh, np.abs(motion_world_positions(back) - positions).max())
    assert worst_decode < 1e-3
    assert worst_bvh < 1e-3


def test_windows_through_the_datamodule(datamodule):
    spec = datamodule.spec
    assert spec.dataset == "humanact12" and spec.num_joints == 24 and spec.feature_dim == 152
    assert spec.styles == ("none",) and spec.contents == humanact12.GROUPS
    batch = next(iter(datamodule.train_dataloader()))
    assert batch["features"].shape == (8, 60, 152)
    assert (batch["style"] == 0).all() and batch["content"].max() < 12
    # Every action has training windows, and test holds every clip.
    train_actions = {datamodule.datasets["train"].labels[i][1] for i, _ in datamodule.datasets["train"].index}
    assert train_actions == set(range(12))
    assert len(datamodule.split_features("test")) == 24


@pytest.fixture(scope="module")
def trained(datamodule, tmp_path_factory) -> dict[str, Path]:
    """A few training steps of the generator and of the action evaluator, saved as checkpoints."""
    folder = tmp_path_factory.mktemp("checkpoints")
    trainer_args = dict(
        accelerator="cpu", max_steps=6, limit_val_batches=1, logger=False, enable_progress_bar=False,
        enable_model_summary=False, num_sanity_val_steps=0, enable_checkpointing=False,
    )  # fmt: skip
    L.seed_everything(0)
    generator = StyledMotionDiffusion(
        datamodule.spec, d_model=32, layers=1, heads=2, timesteps=10, adv_warmup_batches=1
    )
    trainer = L.Trainer(**trainer_args)
    trainer.fit(generator, datamodule)
    trainer.save_checkpoint(folder / "generator.ckpt")
    assert generator.batches_done == 6  # one counted step per batch: the discriminator's is not counted

    evaluator = ActionEvaluator(datamodule.spec, hidden=16, embed_dim=8)
    before = [p.detach().clone() for p in evaluator.parameters()]
    trainer = L.Trainer(**trainer_args)
    trainer.fit(evaluator, datamodule)
    trainer.save_checkpoint(folder / "evaluator.ckpt")
    assert all(torch.isfinite(p).all() for p in evaluator.parameters())
    assert any(not torch.equal(a, b) for a, b in zip(before, evaluator.parameters()))
    return {"generator": folder / "generator.ckpt", "evaluator": folder / "evaluator.ckpt"}


def test_action_evaluator_reads_positions_of_any_length(datamodule, trained):
    evaluator = load_evaluator(trained["evaluator"])
    assert isinstance(evaluator, ActionEvaluator) and evaluator.skeleton.names == NAMES
    raw = torch.from_numpy(np.stack([f[:45] for _, _, f in datamodule.split_features("test")[:4]]))
    positions = evaluator.raw_positions(raw.double()).float()
    features, style, action = evaluator.embed_and_classify(positions)
    assert features.shape == (4, 8) and style.shape == (4, 1) and action.shape == (4, 12)
    assert torch.equal(evaluator.features(positions), features)
    assert not torch.allclose(features[0], features[1])  # different clips, different features
    # Where a clip stands and which way it faces do not matter: it is moved to the origin, facing +Z.
    turn = torch.tensor([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    moved = positions @ turn.T + torch.tensor([3.0, 0.0, -2.0])
    torch.testing.assert_close(evaluator.features(moved), features, atol=1e-4, rtol=1e-4)
    with pytest.raises(WalkdiffError, match=r"expects joint positions \(B, frames, 24, 3\)"):
        evaluator.features(positions[:, :, :20])


def test_generated_motion_exports_to_bvh_on_the_smpl_skeleton(trained, tmp_path):
    generator = StyledMotionDiffusion.load_from_checkpoint(trained["generator"], weights_only=False)
    files = SampleClips(content="boxing", sampler="ddim", steps=2).write(generator, None, "", folder=tmp_path)
    assert [f.name for f in files] == ["none_boxing.bvh", "styles.gif", "styles.png"]
    motion = read_bvh(files[0])
    # 4 s, several windows made as `walkdiff sample` makes them, at the model's 20 fps.
    assert motion.skeleton.names == NAMES and motion.num_frames == 80 and motion.fps == pytest.approx(20)
    assert np.isfinite(motion_world_positions(motion)).all()


def test_evaluate_reports_the_protocol_without_styles(trained, tmp_path):
    out = tmp_path / "report"
    args = ["evaluate", "--ckpt", str(trained["generator"]), "--evaluator", str(trained["evaluator"])]
    args += ["--out", str(out), "--num", "24", "--repeats", "2", "--sampler", "ddim", "--steps", "2"]
    assert main(args + ["--stride", "10"]) == 0
    report = json.loads((out / "report.json").read_text())
    # The same generated windows grounded and as sampled, then the real references.
    assert list(report["rows"]) == ["generated", "generated, not grounded", "real test", "real train vs test"]
    assert report["data"]["contents"] == list(humanact12.GROUPS)
    assert report["data"]["clips"]["test"] == 24  # the protocol's reference is all of the data
    for row in report["rows"].values():
        assert "style_acc" not in row and {"fmd", "content_acc", "diversity", "multimodality"} <= set(row)
        assert row["fmd"]["n"] == 2
    # An untrained generator is far from the real data.
    assert report["rows"]["generated"]["fmd"]["mean"] > report["rows"]["real test"]["fmd"]["mean"]
    table = (out / "report.md").read_text()
    assert "Content acc." in table and "Style acc." not in table


@pytest.mark.parametrize(
    ("config", "tiny"),
    [
        ("humanact12.yaml", ["--model.init_args.d_model", "32", "--model.init_args.layers", "1"]),
        ("evaluator_humanact12.yaml", ["--model.init_args.hidden", "16"]),
    ],
)
def test_configs_train_through_the_cli(root, tmp_path, monkeypatch, config, tiny):
    monkeypatch.chdir(tmp_path)  # the configs write checkpoints/ under the working directory
    monkeypatch.setattr("sys.argv", ["walkdiff"])  # LightningCLI warns about pytest's own arguments
    data = ["--data.init_args.root", str(root), "--data.init_args.cache_dir", str(root / "cache")]
    data += ["--data.init_args.batch_size", "8", "--data.init_args.num_workers", "0"]
    data += ["--data.init_args.preprocess_workers", "1"]
    trainer = ["--trainer.logger", "false", "--trainer.accelerator", "cpu", "--trainer.max_epochs", "1"]
    trainer += ["--trainer.limit_train_batches", "2", "--trainer.limit_val_batches", "1"]
    trainer += ["--trainer.val_check_interval", "2"]  # the configs validate every few hundred batches
    trainer += ["--trainer.check_val_every_n_epoch", "1"]  # checkpoints are written after validation
    assert main(["fit", "--config", str(CONF / config), *data, *trainer, *tiny]) == 0
    written = list((tmp_path / "checkpoints").glob("*/last.ckpt"))
    assert len(written) == 1
    assert torch.load(written[0], weights_only=False)["hyper_parameters"]["data_spec"]["window"] == 60


# ---------------------------------------------------------------- bad files


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: d.pop("joints3D"), "missing key 'joints3D'"),
        (lambda d: d["y"].pop(), "clip counts poses 24, joints3D 24, y 23"),
        (lambda d: d.__setitem__("y", 3), "y is of type int: expected a list, one entry per clip"),
        (
            lambda d: d["poses"].__setitem__(3, d["poses"][3][:, :69]),
            "poses[3] has shape (3, 69): expected (T, 72)",
        ),
        (
            lambda d: d["joints3D"].__setitem__(2, d["joints3D"][2][:-1]),
            "joints3D[2] has shape (2, 24, 3): expected (3, 24, 3)",
        ),
        (lambda d: d["y"].__setitem__(4, 12), "y[4] is 12: expected an action id 0-11"),
    ],
)
def test_bad_files_name_what_is_wrong(tmp_path, change, message):
    path = write_pkl(tmp_path / "humanact12" / humanact12.FILE_NAME, per_action=2, frames=(3, 4))
    data = pickle.loads(path.read_bytes())
    change(data)
    path.write_bytes(pickle.dumps(data))
    with pytest.raises(WalkdiffError) as error:
        humanact12.list_clips(path.parent)
    assert message in str(error.value) and str(path) in str(error.value)


def test_missing_or_foreign_file(tmp_path):
    folder = tmp_path / "humanact12"
    folder.mkdir()
    with pytest.raises(WalkdiffError, match="humanact12poses.pkl not found"):
        humanact12.list_clips(folder)
    (folder / humanact12.FILE_NAME).write_bytes(pickle.dumps([1, 2, 3]))
    with pytest.raises(WalkdiffError, match="found a list; expected a pickled dict with keys poses"):
        humanact12.list_clips(folder)
    (folder / humanact12.FILE_NAME).write_text("not a pickle")
    with pytest.raises(WalkdiffError, match="cannot unpickle"):
        humanact12.list_clips(folder)
