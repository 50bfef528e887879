"""Bad input as a new user types it, through every command: one line naming what is wrong, exit 1,
no traceback, nothing written."""

from __future__ import annotations

import pytest

from walkdiff.cli.main import build_parser, main


@pytest.fixture(autouse=True)
def plain_argv(monkeypatch):
    monkeypatch.setattr("sys.argv", ["walkdiff"])


@pytest.fixture
def files(tmp_path, monkeypatch):
    """Broken and missing inputs in a scratch folder (the working directory, so outputs stay there)."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "empty.ckpt").write_bytes(b"")
    (tmp_path / "garbage.ckpt").write_bytes(b"PK\x03\x04 not really a checkpoint")
    (tmp_path / "text.bvh").write_text("HIERARCHY\nROOT Hips\n{\n")
    point = "ROOT Hips\n{\n  OFFSET 0 0 0\n  CHANNELS 3 Xposition Yposition Zposition\n}\n"
    (tmp_path / "point.bvh").write_text(
        f"HIERARCHY\n{point}MOTION\nFrames: 2\nFrame Time: 0.1\n0 0 0\n1 0 0\n"
    )
    (tmp_path / "file").write_text("a file where a folder is expected")
    (tmp_path / "noise.wav").write_bytes(b"RIFF....WAVEfmt ")
    (tmp_path / "path.json").write_text("[[0, 0], [1e400, 0]]")
    (tmp_path / "folder").mkdir()
    (tmp_path / "passwd").write_text("root:x:0:0:root:/root:/bin/bash\n")
    (tmp_path / "transfer.csv").write_text("file,source,style\ntext.bvh,text.bvh,old\n")
    (tmp_path / "outside.csv").write_text("file,source,style\ntext.bvh,../text.bvh,old\n")
    (tmp_path / "twice.csv").write_text("file,source,style\ntext.bvh,text.bvh,old\ntext.bvh,text.bvh,sexy\n")
    return tmp_path


STYLE = ["--style", "angry"]
CHECKPOINT_USERS = [
    ["sample", "--out", "o", *STYLE],
    ["transfer", "--out", "o", "--input", "text.bvh", *STYLE],
    ["walk", "--out", "o", "--path", "path.json", *STYLE],
    ["gesture", "--out", "o", "--audio", "noise.wav"],
    ["evaluate", "--out", "o", "--evaluator", "garbage.ckpt"],
    ["evaluate-gesture", "--out", "o"],
    ["distill", "--out", "student.ckpt"],
    ["export", "--out", "exported"],
    ["control"],
    ["play", "--out", "o", "--script", "s.jsonl"],
    ["inbetween", "text.bvh", "text.bvh", "--frames", "5", "--out", "o.bvh"],
    ["edit", "text.bvh", "--keep", "legs", "--out", "o.bvh", *STYLE],
]

CASES = {
    # (arguments, words the message must hold)
    "inspect a missing file": (["inspect", "missing.bvh"], ["missing.bvh"]),
    "inspect a truncated BVH": (["inspect", "text.bvh"], ["text.bvh"]),
    "convert a missing file": (["convert", "missing.bvh", "out.bvh"], ["missing.bvh"]),
    "convert onto itself": (["convert", "text.bvh", "text.bvh", "--overwrite"], ["text.bvh"]),
    "convert a bad rate": (["convert", "text.bvh", "o.bvh", "--fps", "inf"], ["--fps", "finite"]),
    "retarget a missing file": (
        ["retarget", "missing.bvh", "--to", "smpl", "--out", "o.bvh"],
        ["missing.bvh"],
    ),
    "retarget to an unknown rig": (
        ["retarget", "text.bvh", "--to", "maya", "--out", "o.bvh"],
        ["maya", "smpl"],
    ),
    "scan a missing folder": (["data", "scan", "nowhere"], ["nowhere"]),
    "scan an empty folder": (["data", "scan", "folder"], ["folder", ".bvh"]),
    "scan a fraction over 1": (["data", "scan", "folder", "--val-fraction", "1.5"], ["--val-fraction"]),
    "score a missing folder": (
        ["score", "nowhere", "--evaluator", "garbage.ckpt", "--out", "o"],
        ["nowhere"],
    ),
    "score a folder and a manifest": (
        ["score", "folder", "--transfer", "transfer.csv", "--evaluator", "e", "--out", "o"],
        ["--transfer", "not both"],
    ),
    "score a manifest naming a file outside its folder": (
        ["score", "--transfer", "outside.csv", "--evaluator", "e", "--out", "o"],
        ["outside.csv:2: source '../text.bvh'", "outside the manifest's folder", "--allow-outside"],
    ),
    "score a manifest naming an output twice": (
        ["score", "--transfer", "twice.csv", "--evaluator", "e", "--out", "o"],
        ["twice.csv:3", "output of line 2 too"],
    ),
    "inspect a file that is not BVH": (["inspect", "passwd"], ["passwd:1: not a BVH file"]),
    "score into a file": (["score", "folder", "--evaluator", "garbage.ckpt", "--out", "file"], ["file"]),
    "score a bad stride": (
        ["score", "folder", "--evaluator", "e", "--out", "o", "--stride", "-2"],
        ["--stride"],
    ),
    "sample into a file": (["sample", "--ckpt", "garbage.ckpt", "--out", "file", *STYLE], ["file"]),
    "sample zero frames": (["sample", "--ckpt", "g", "--out", "o", *STYLE, "--frames", "0"], ["--frames"]),
    "sample a word for a number": (
        ["sample", "--ckpt", "g", "--out", "o", *STYLE, "--num", "ten"],
        ["--num"],
    ),
    "sample an unknown sampler": (
        ["sample", "--ckpt", "g", "--out", "o", *STYLE, "--sampler", "x"],
        ["--sampler"],
    ),
    "sample at a guidance of 1e30": (
        ["sample", "--ckpt", "g", "--out", "o", *STYLE, "--guidance", "1e30"],
        ["--guidance", "[0, 100]", "1e30"],
    ),
    "transfer at strength 1.5": (
        ["transfer", "--ckpt", "g", "--out", "o", "--input", "i", *STYLE, "--strength", "1.5"],
        ["--strength", "(0, 1]"],
    ),
    "walk at a negative speed": (
        ["walk", "--ckpt", "g", "--out", "o", "--path", "p", *STYLE, "--speed", "-1"],
        ["--speed"],
    ),
    "gesture with no streams": (
        ["gesture", "--ckpt", "g", "--audio", "a", "--out", "o", "--num", "0"],
        ["--num"],
    ),
    "gesture --rate without --stream": (
        ["gesture", "--ckpt", "g", "--audio", "a", "--out", "o", "--rate", "16000"],
        ["--rate needs --stream"],
    ),
    "gesture --stream at a zero rate": (
        ["gesture", "--stream", "--ckpt", "g", "--audio", "-", "--out", "o", "--rate", "0"],
        ["--rate"],
    ),
    "walk --idle without --stream": (
        ["walk", "--ckpt", "g", "--out", "o", "--path", "p", *STYLE, "--idle", "1"],
        ["--idle needs --stream"],
    ),
    "bench stream with no frames": (["bench", "stream", "--out", "s.json", "--frames", "0"], ["--frames"]),
    "bench stream with a word for threads": (
        ["bench", "stream", "--out", "s.json", "--threads", "two"],
        ["--threads"],
    ),
    "gesture with steps for ddpm": (
        ["gesture", "--ckpt", "g", "--audio", "a", "--out", "o", "--steps", "10"],
        ["--steps", "ddpm"],
    ),
    "gesture with eta for dpmpp": (
        ["gesture", "--ckpt", "g", "--audio", "a", "--out", "o", "--sampler", "dpmpp", "--eta", "0.5"],
        ["--eta", "ddim only"],
    ),
    "gesture with an unknown sampler": (
        ["gesture", "--ckpt", "g", "--audio", "a", "--out", "o", "--sampler", "heun"],
        ["--sampler"],
    ),
    "evaluate-gesture with zero steps": (
        ["evaluate-gesture", "--ckpt", "g", "--out", "o", "--sampler", "ddim", "--steps", "0"],
        ["--steps"],
    ),
    "evaluate-gesture with eta over 1": (
        ["evaluate-gesture", "--ckpt", "g", "--out", "o", "--sampler", "ddim", "--eta", "2"],
        ["--eta"],
    ),
    "walk with steps for ddpm": (
        ["walk", "--ckpt", "g", "--out", "o", "--path", "p", *STYLE, "--steps", "5"],
        ["--steps", "ddpm"],
    ),
    "evaluate-gesture at a nan threshold": (
        ["evaluate-gesture", "--ckpt", "g", "--out", "o", "--pck-threshold", "nan"],
        ["--pck-threshold"],
    ),
    "bench with no output": (["bench", "data"], ["--out"]),
    "bench view a missing file": (["bench", "view", "missing.bvh", "--out", "v.json"], ["missing.bvh"]),
    "an unknown command": (["train"], ["train", "choose from"]),
    "view a missing file": (["view", "missing.bvh", "--port", "0"], ["missing.bvh"]),
    "view a truncated BVH": (["view", "text.bvh", "--port", "0"], ["text.bvh"]),
    # One joint and no end site: a skeleton of no height, whose units cannot be told (issue 33).
    "inspect a one-point skeleton": (["inspect", "point.bvh"], ["point.bvh", "body_height"]),
    "convert a one-point skeleton": (["convert", "point.bvh", "o.glb"], ["point.bvh", "body_height"]),
    "view a one-point skeleton": (["view", "point.bvh", "--port", "0"], ["point.bvh", "body_height"]),
    "upgrade without --trust": (
        ["checkpoint", "upgrade", "garbage.ckpt", "--out", "new.ckpt"],
        ["garbage.ckpt", "--trust"],
    ),
    "upgrade a missing file": (
        ["checkpoint", "upgrade", "missing.ckpt", "--out", "new.ckpt", "--trust"],
        ["missing.ckpt"],
    ),
    "upgrade a file that is not a checkpoint": (
        ["checkpoint", "upgrade", "text.bvh", "--out", "new.ckpt", "--trust"],
        ["text.bvh", "not a readable checkpoint"],
    ),
    "upgrade onto itself": (
        ["checkpoint", "upgrade", "garbage.ckpt", "--out", "garbage.ckpt", "--trust"],
        ["--out", "another file"],
    ),
    "inbetween into a file that is not BVH": (
        ["inbetween", "text.bvh", "text.bvh", "--frames", "5", "--ckpt", "g", "--out", "o.txt"],
        ["--out", "OUT.bvh", "o.txt"],
    ),
    "inbetween a word for frames": (
        ["inbetween", "text.bvh", "text.bvh", "--frames", "ten", "--ckpt", "g", "--out", "o.bvh"],
        ["--frames"],
    ),
    "edit without --keep": (["edit", "text.bvh", "--ckpt", "g", "--out", "o.bvh"], ["--keep"]),
    "an unknown option": (["sample", "--ckpt", "g", "--out", "o", *STYLE, "--colour", "red"], ["--colour"]),
}
for command in CHECKPOINT_USERS:
    for kind in ("empty", "garbage", "missing"):
        extra = ["--teacher" if command[0] == "bench" else "--ckpt", f"{kind}.ckpt"]
        CASES[f"{command[0]} with a {kind} checkpoint"] = ([*command, *extra], [f"{kind}.ckpt"])


@pytest.mark.parametrize("name", sorted(CASES))
def test_bad_input_is_one_line_naming_it(files, capsys, name):
    args, words = CASES[name]
    before = sorted(p.name for p in files.rglob("*"))
    assert main(args) == 1
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert err and err[-1].startswith("walkdiff: error: "), captured.err
    assert "Traceback" not in captured.err and "usage:" not in captured.err
    for word in words:
        assert word in err[-1], (word, err[-1])
    assert sorted(p.name for p in files.rglob("*")) == before, "nothing written"


def test_a_file_that_is_not_motion_is_never_echoed(files, capsys):
    """Issue 33: an error quoted the first line of any file given as motion (/etc/passwd)."""
    for args in (["inspect", "passwd"], ["convert", "passwd", "o.bvh"], ["view", "passwd", "--port", "0"]):
        assert main(args) == 1
        err = capsys.readouterr().err
        assert "passwd:1: not a BVH file" in err and "root" not in err, err


def test_every_command_is_covered():
    commands = set(build_parser()._subparsers._group_actions[0].choices)
    covered = {CASES[name][0][0] for name in CASES}
    assert commands - covered == set()
