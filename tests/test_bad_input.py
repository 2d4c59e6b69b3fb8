"""Bad input, table-driven, across every command (issue 12): each case must exit non-zero with at most one
line on stderr and no traceback, name the file or flag at fault, and leave every file that was there
byte-identical (and add none: a refusal writes nothing).

Each case builds its scene in a fresh temporary folder (the working folder while it runs) from small
inputs made once per session, runs `spare-twin ARGV` in-process, and compares the folder's tree before
and after. A case that is wrongly accepted may start real work: a time budget stops it (and fails it).
A handful run through the installed console script, for real exit codes and tracebacks; the `--json`
cases run there too, since C libraries print on file descriptor 1.
"""

from __future__ import annotations

import contextlib
import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import textwrap
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest
from capture_helpers import TUM_K, TUM_PAIR, seven_scenes
from conftest import REPO, refused_before_torch, stderr_lines, tree

from spare_twin.cli import main

SCRIPT = REPO / ".venv" / "bin" / "spare-twin"
FAST_RENDER = ["--frames", "1", "--resolution", "32x24"]
FAST_DATASET = ["--instances", "1", "--frames", "1"]
TINY_TRAIN = {
    "preset": "geo-depth-mv-count",
    "net": {"channels": [4, 8], "fc_hidden": 16, "dropout": 0.0},
    "train": {"epochs": 1, "batch_size": 6, "samples_per_epoch": None, "val_samples": None, "threads": 1},
}


# -- the inputs, made once -------------------------------------------------------------------------


@pytest.fixture(scope="session")
def sources(printed_object, tmp_path_factory) -> dict[str, Path]:
    """Small inputs every case copies from: an object, recordings, a synthetic data set, real frames."""
    from spare_twin.dataset.synthetic import SyntheticSpec, write_synthetic
    from spare_twin.sim.render import RenderConfig, render_recording

    root = tmp_path_factory.mktemp("bad_input_sources")
    obj = printed_object.root
    hand = dict(resolution="64x48", path="handheld", motion="static", segmentation=False)
    render_recording(obj, root / "rec", RenderConfig(frames=3, **hand), progress=False)
    render_recording(obj, root / "rec1", RenderConfig(frames=1, **hand), progress=False)
    render_recording(obj, root / "rig", RenderConfig(frames=1, resolution="64x48"), progress=False)
    write_synthetic(root / "syn", SyntheticSpec(sizes=(("train", 6), ("val", 6), ("test", 6)), seed=5))
    scenes = seven_scenes(root / "scenes")
    return {"obj": obj, "tum": TUM_PAIR, "scenes": scenes} | {k: root / k for k in ("rec", "rec1", "rig", "syn")}


class W:
    """A case's working folder: copies of the inputs it asks for, and small helpers to spoil them."""

    def __init__(self, root: Path, sources: dict[str, Path]):
        self.root, self.sources = root, sources

    def copy(self, what: str, name: str | None = None) -> str:
        name = name or what
        if not (self.root / name).exists():
            shutil.copytree(self.sources[what], self.root / name)
        return name

    def obj(self, name="obj") -> str:
        return self.copy("obj", name)

    def rec(self, name="rec", what="rec") -> str:
        return self.copy(what, name)

    def file(self, name: str, data: bytes | str = "my notes\n") -> str:
        p = self.root / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(data.encode() if isinstance(data, str) else data)
        return name

    def json(self, name: str, obj) -> str:
        return self.file(name, json.dumps(obj))

    def folder(self, name="mine") -> str:
        """A user's folder: notes and a subfolder with data."""
        self.file(f"{name}/notes.txt")
        self.file(f"{name}/raw/capture.bin", bytes(range(256)))
        return name

    def empty(self, name="empty") -> str:
        (self.root / name).mkdir()
        return name

    def truncate(self, rel: str, keep: float = 0.5) -> None:
        p = self.root / rel
        data = p.read_bytes()
        p.write_bytes(data[: int(len(data) * keep)])

    def remove(self, pattern: str) -> None:
        for p in self.root.glob(pattern):
            p.unlink()

    def copy_file(self, src: str, dst: str) -> None:
        shutil.copy(self.root / src, self.root / dst)

    def edit_json(self, rel: str, **changes) -> None:
        p = self.root / rel
        d = json.loads(p.read_text())
        for k, v in changes.items():
            if v is ...:
                d.pop(k)
            else:
                d[k] = v
        p.write_text(json.dumps(d))

    def imported(self, name="real") -> str:
        """A real capture: the 7-Scenes frames imported with `capture import`."""
        assert main(["capture", "import", self.copy("scenes", "_raw"), "--layout", "7scenes", "--out", name]) == 0
        shutil.rmtree(self.root / "_raw")
        return name

    def chain(self, **changes) -> str:
        spec = {"n_links": 2, "link_lengths_pu": [1.5, 0.6, 0.5], "colors": ["red", "blue", "green"]}
        for k, v in changes.items():
            if v is ...:
                spec.pop(k)
            else:
                spec[k] = v
        return self.json("spec.json", spec)

    @property
    def model(self) -> str:
        return str(REPO / "models" / "geo-mv-multitask.pt")

    def garbage_model(self) -> str:
        return self.file("bad.pt", b"PK\x03\x04 this is not a checkpoint" * 10)


@dataclass(frozen=True)
class Case:
    id: str
    args: str
    """The arguments after `spare-twin`, split like a shell; {model} is the shipped checkpoint."""
    names: str
    """What the message must name: the file or flag at fault ("a|b": either, "a&b": both)."""
    setup: Callable[[W], object] = lambda w: None
    """Builds the scene in the working folder: copies of inputs, spoiled ones, a user's files."""
    forbid: tuple[str, ...] = ()
    """Misleading words the message must not hold."""
    budget_s: float = 8.0
    """Seconds before a case that was accepted and started real work is stopped (refusals take well under one)."""

    def argv(self, w: W) -> list[str]:
        self.setup(w)
        return [a.replace("{model}", w.model) for a in shlex.split(self.args)]

    def named_in(self, message: str) -> bool:
        if "&" in self.names:
            return all(n in message for n in self.names.split("&"))
        return any(n in message for n in self.names.split("|"))


C = Case
R = " --frames 1 --resolution 32x24"  # renders that are accepted stay short
D = " --instances 1 --frames 1"
M = " --model {model}"
MP = M + " --outside-rig"  # the image network on hand-held recordings, which it refuses otherwise
TRAIN = "train --config cfg.json --data syn --out run --epochs 1"
COLOR1, DEPTH1 = "rec/cameras/cam0/color/000001.png", "rec/cameras/cam0/depth/000001.png"


def obj(w):
    return w.obj()


def rec(w):
    return w.rec()


def syn(w):
    return w.copy("syn")


def scenes(w):
    return w.copy("scenes", "src")


def train_inputs(w):
    return w.copy("syn"), w.json("cfg.json", TINY_TRAIN)


def chain(**changes):
    return lambda w: w.chain(**changes)


# fmt: off
CASES = [
    # object: outputs
    C("object-out-user-folder", "object --links 2 --out mine", "mine", lambda w: w.folder()),
    C("object-out-user-subfolder-only", "object --links 2 --out m", "m", lambda w: w.file("m/raw/a.bin", b"1")),
    C("object-out-a-recording", "object --links 2 --out rec", "rec", rec),
    C("object-out-a-file", "object --links 2 --out notes.txt", "notes.txt", lambda w: w.file("notes.txt")),
    C("object-out-dot", "object --links 2 --out .", "--out|current"),
    C("object-out-under-a-file", "object --links 2 --out notes.txt/o", "notes.txt", lambda w: w.file("notes.txt")),
    C("object-out-unwritable", "object --links 2 --out /proc/self/obj", "/proc/self"),
    # object: options and configurations
    C("object-seed-negative", "object --links 2 --seed -5 --out o", "--seed"),
    C("object-links-zero", "object --links 0 --out o", "--links"),
    C("object-links-seven", "object --links 7 --out o", "--links"),
    C("object-links-not-a-number", "object --links two --out o", "--links"),
    C("object-print-scale-negative", "object --links 2 --print-scale -1 --out o", "--print-scale"),
    C("object-print-scale-nan", "object --links 2 --print-scale nan --out o", "--print-scale"),
    C("object-clearance-huge", "object --links 2 --clearance 5 --out o", "--clearance"),
    C("object-bed-garbage", "object --links 2 --bed big --out o", "--bed"),
    C("object-bed-negative", "object --links 2 --bed -200x200 --out o", "--bed"),
    C("object-name-with-slash", "object --links 2 --name a/b --out o", "--name"),
    C("object-config-lengths-string", "object --config spec.json --out o", "link_lengths_pu",
      chain(link_lengths_pu="long")),
    C("object-config-n-links-string", "object --config spec.json --out o", "n_links", chain(n_links="three")),
    C("object-config-no-colors-and-bad-lengths", "object --config spec.json --out o", "colors&link_lengths_pu",
      chain(colors=..., link_lengths_pu="long")),
    C("object-config-colors-string", "object --config spec.json --out o", "colors", chain(colors="red")),
    C("object-config-lengths-null", "object --config spec.json --out o", "link_lengths_pu",
      chain(link_lengths_pu=None)),
    C("object-config-n-links-fraction", "object --config spec.json --out o", "n_links", chain(n_links=2.5)),
    C("object-config-n-links-bool", "object --config spec.json --out o", "n_links", chain(n_links=True)),
    C("object-config-seed-negative", "object --config spec.json --out o", "seed", chain(seed=-3)),
    C("object-config-print-scale-string", "object --config spec.json --out o", "print_scale",
      chain(print_scale="big")),
    C("object-config-parts-string", "object --config spec.json --out o", "link_width_mm",
      chain(parts={"link_width_mm": "wide"})),
    C("object-config-name-path", "object --config spec.json --out o", "name", chain(name="../x")),
    C("object-config-unknown-key", "object --config spec.json --out o", "bogus", chain(bogus=1)),
    C("object-config-missing", "object --config nope.json --out o", "nope.json"),
    C("object-config-not-json", "object --config spec.json --out o", "spec.json", lambda w: w.file("spec.json", "{")),
    C("object-config-a-list", "object --config spec.json --out o", "spec.json", lambda w: w.json("spec.json", [1])),
    C("object-config-a-folder", "object --config obj --out o", "obj", obj),
    # render: outputs
    C("render-out-is-the-object", "render obj --out obj" + R, "obj", obj),
    C("render-out-inside-the-object", "render obj --out obj/rec" + R, "obj", obj),
    C("render-out-around-the-object", "render work/obj --out work" + R, "work", lambda w: w.obj("work/obj")),
    C("render-out-user-folder", "render obj --out mine" + R, "mine", lambda w: (w.obj(), w.folder())),
    C("render-out-a-real-capture", "render obj --out real" + R, "real", lambda w: (w.obj(), w.imported("real"))),
    C("render-out-dot", "render obj --out ." + R, "--out|current", obj),
    C("render-out-under-a-file", "render obj --out notes.txt/r" + R, "notes.txt",
      lambda w: (w.obj(), w.file("notes.txt"))),
    # render: options
    C("render-seed-negative", "render obj --out r --seed -1" + R, "--seed", obj),
    C("render-frames-zero", "render obj --out r --frames 0", "--frames", obj),
    C("render-frames-not-a-number", "render obj --out r --frames many", "--frames", obj),
    C("render-fps-zero", "render obj --out r --fps 0" + R, "--fps", obj),
    C("render-fps-nan", "render obj --out r --fps nan" + R, "--fps", obj),
    C("render-resolution-tiny", "render obj --out r --frames 1 --resolution 4x4", "--resolution", obj),
    C("render-resolution-garbage", "render obj --out r --frames 1 --resolution big", "--resolution", obj),
    C("render-rig-unknown", "render obj --out r --rig nosuch" + R, "nosuch", obj),
    C("render-noise-unknown", "render obj --out r --noise nosuch" + R, "nosuch", obj),
    C("render-hide-poses-on-rig", "render obj --out r --hide-poses" + R, "--hide-poses", obj),
    # render: the object folder
    C("render-object-missing", "render nowhere --out r" + R, "nowhere"),
    C("render-object-empty-folder", "render empty --out r" + R, "empty", lambda w: w.empty()),
    C("render-object-is-a-file", "render notes.txt --out r" + R, "notes.txt", lambda w: w.file("notes.txt")),
    C("render-object-json-corrupt", "render obj --out r" + R, "object.json",
      lambda w: (w.obj(), w.file("obj/object.json", "{"))),
    C("render-object-urdf-missing", "render obj --out r" + R, ".urdf", lambda w: (w.obj(), w.remove("obj/*.urdf"))),
    C("render-stl-truncated", "render obj --out r" + R, "link2.stl", lambda w: (w.obj(), w.truncate("obj/link2.stl"))),
    C("render-stl-empty", "render obj --out r" + R, "link1.stl", lambda w: (w.obj(), w.truncate("obj/link1.stl", 0))),
    C("render-stl-another-part", "render obj --out r" + R, "link2.stl",
      lambda w: (w.obj(), w.copy_file("obj/link1.stl", "obj/link2.stl"))),
    C("render-stl-missing", "render obj --out r" + R, "link2.stl", lambda w: (w.obj(), w.remove("obj/link2.stl"))),
    # dataset
    C("dataset-seed-negative", "dataset --out d --seed -1" + D, "--seed"),
    C("dataset-instances-zero", "dataset --out d --instances 0", "--instances"),
    C("dataset-instances-missing", "dataset --out d", "--instances"),
    C("dataset-workers-zero", "dataset --out d --workers 0" + D, "--workers"),
    C("dataset-workers-negative", "dataset --out d --workers -2" + D, "--workers"),
    C("dataset-frames-zero", "dataset --out d --instances 1 --frames 0", "--frames"),
    C("dataset-rig-unknown", "dataset --out d --rig nosuch" + D, "nosuch"),
    C("dataset-out-user-folder", "dataset --out mine" + D, "mine", lambda w: w.folder()),
    C("dataset-out-a-recording", "dataset --out rec" + D, "rec", rec),
    C("dataset-out-a-file", "dataset --out notes.txt" + D, "notes.txt", lambda w: w.file("notes.txt")),
    C("dataset-out-dot", "dataset --out ." + D, "--out|current"),
    C("dataset-out-under-a-file", "dataset --out notes.txt/d" + D, "notes.txt", lambda w: w.file("notes.txt")),
    C("dataset-other-seed", "dataset --out d --seed 6" + D, "--seed",
      lambda w: w.json("d/dataset.json", {"format": "spare-twin-dataset/1", "seed": 5, "generator": {}})),
    # train
    C("train-preset-unknown", "train --preset nosuch --data syn --out run", "nosuch", syn),
    C("train-config-not-json", "train --config cfg.json --data syn --out run", "cfg.json",
      lambda w: (syn(w), w.file("cfg.json", "{"))),
    C("train-config-net-string", "train --config cfg.json --data syn --out run", "cfg.json|net",
      lambda w: (syn(w), w.json("cfg.json", {**TINY_TRAIN, "net": "big"}))),
    C("train-data-missing", "train --config cfg.json --data nowhere --out run", "nowhere",
      lambda w: w.json("cfg.json", TINY_TRAIN)),
    C("train-epochs-zero", TRAIN + " --epochs 0", "--epochs", train_inputs),
    C("train-batch-size-zero", TRAIN + " --batch-size 0", "--batch-size", train_inputs),
    C("train-lr-negative", TRAIN + " --lr -1", "--lr", train_inputs),
    C("train-lr-nan", TRAIN + " --lr nan", "--lr", train_inputs),
    C("train-seed-negative", TRAIN + " --seed -1", "--seed", train_inputs),
    C("train-threads-negative", TRAIN + " --threads -1", "--threads", train_inputs),
    C("train-out-user-folder", TRAIN.replace("run", "mine"), "mine", lambda w: (train_inputs(w), w.folder())),
    C("train-out-is-the-data", TRAIN.replace("run", "syn"), "syn", train_inputs),
    C("train-out-inside-the-data", TRAIN.replace("run", "syn/run"), "syn", train_inputs),
    C("train-resume-nothing", TRAIN.replace("run", "empty") + " --resume", "empty|--resume",
      lambda w: (train_inputs(w), w.empty())),
    # evaluate
    C("evaluate-model-missing", "evaluate --model nope.pt --data syn", "nope.pt", syn),
    C("evaluate-model-garbage", "evaluate --model bad.pt --data syn", "bad.pt",
      lambda w: (syn(w), w.garbage_model())),
    C("evaluate-model-is-json", "evaluate --model m.json --data syn", "m.json",
      lambda w: (syn(w), w.json("m.json", {}))),
    C("evaluate-data-missing", "evaluate --data nowhere" + M, "nowhere"),
    C("evaluate-data-empty", "evaluate --data empty" + M, "empty", lambda w: w.empty()),
    C("evaluate-split-unknown", "evaluate --data syn --split nope" + M, "nope", syn),
    C("evaluate-batch-size-zero", "evaluate --data syn --batch-size 0" + M, "--batch-size", syn),
    C("evaluate-max-samples-zero", "evaluate --data syn --max-samples 0" + M, "--max-samples", syn),
    C("evaluate-out-user-folder", "evaluate --data syn --out mine" + M, "mine", lambda w: (syn(w), w.folder())),
    C("evaluate-out-is-the-data", "evaluate --data syn --out syn" + M, "syn", syn),
    # predict
    C("predict-recording-missing", "predict nowhere" + MP, "nowhere"),
    C("predict-recording-empty-folder", "predict empty" + MP, "empty", lambda w: w.empty()),
    C("predict-recording-json-corrupt", "predict rec" + MP, "recording.json",
      lambda w: (rec(w), w.file("rec/recording.json", "{"))),
    C("predict-recording-json-no-cameras", "predict rec" + MP, "recording.json",
      lambda w: (rec(w), w.edit_json("rec/recording.json", cameras=...))),
    C("predict-recording-json-frames-string", "predict rec" + MP, "recording.json|frames",
      lambda w: (rec(w), w.edit_json("rec/recording.json", frames="three"))),
    C("predict-depth-zero-size", "predict rec" + MP, "000001.png", lambda w: (rec(w), w.truncate(DEPTH1, 0))),
    C("predict-depth-truncated", "predict rec" + MP, "000001.png", lambda w: (rec(w), w.truncate(DEPTH1))),
    C("predict-depth-wrong-size", "predict rec" + MP, "000001.png",
      lambda w: (rec(w), w.copy_file(str(TUM_PAIR / "1_depth.png"), DEPTH1))),
    C("predict-model-garbage", "predict rec --model bad.pt", "bad.pt", lambda w: (rec(w), w.garbage_model())),
    C("predict-model-missing", "predict rec --model nope.pt", "nope.pt", rec),
    C("predict-frame-out-of-range", "predict rec --frame 99" + MP, "--frame", rec),
    C("predict-frame-negative", "predict rec --frame -1" + MP, "--frame", rec),
    C("predict-camera-unknown", "predict rec --camera nosuch" + MP, "nosuch", rec),
    C("predict-n-links-zero", "predict rec --n-links 0" + MP, "--n-links", rec),
    C("predict-n-links-seven", "predict rec --n-links 7" + MP, "--n-links", rec),
    C("predict-print-scale-zero", "predict rec --print-scale 0" + MP, "--print-scale", rec),
    C("predict-print-scale-negative", "predict rec --print-scale -0.1" + MP, "--print-scale", rec),
    # capture import
    C("import-out-is-the-source", f"capture import tum --layout tum --intrinsics {TUM_K} --out tum", "tum",
      lambda w: w.copy("tum")),
    C("import-out-inside-the-source", "capture import src --layout 7scenes --out src/rec", "src", scenes),
    C("import-out-user-folder", "capture import src --layout 7scenes --out mine", "mine",
      lambda w: (scenes(w), w.folder())),
    C("import-out-an-object", "capture import src --layout 7scenes --out obj", "obj", lambda w: (scenes(w), obj(w))),
    C("import-out-dot", "capture import src --layout 7scenes --out .", "--out|current", scenes),
    C("import-colour-zero-size", "capture import src --layout 7scenes --out r", "frame-000019.color.png",
      lambda w: (scenes(w), w.truncate("src/frame-000019.color.png", 0))),
    C("import-depth-zero-size", "capture import src --layout 7scenes --out r", "frame-000019.depth.png",
      lambda w: (scenes(w), w.truncate("src/frame-000019.depth.png", 0))),
    C("import-source-missing", "capture import nowhere --layout 7scenes --out r", "nowhere"),
    C("import-stride-zero", "capture import src --layout 7scenes --out r --stride 0", "--stride", scenes),
    C("import-max-frames-zero", "capture import src --layout 7scenes --out r --max-frames 0", "--max-frames", scenes),
    C("import-depth-scale-negative", "capture import src --layout 7scenes --out r --depth-scale -0.001",
      "--depth-scale", scenes),
    C("import-fps-zero", "capture import src --layout 7scenes --out r --fps 0", "--fps", scenes),
    C("import-intrinsics-garbage", "capture import tum --layout tum --intrinsics a,b,c,d --out r", "--intrinsics",
      lambda w: w.copy("tum")),
    C("import-intrinsics-negative", "capture import tum --layout tum --intrinsics=-520,-520,320,240 --out r",
      "--intrinsics", lambda w: w.copy("tum")),
    C("import-bag-not-a-bag", "capture import fake.bag --layout bag --out r", "fake.bag",
      lambda w: w.file("fake.bag", b"\0" * 64)),
    # capture register
    C("register-one-frame", "capture register rec", "rec&frame", lambda w: w.rec("rec", "rec1"),
      forbid=("depth beyond",)),
    C("register-voxel-zero", "capture register rec --voxel 0", "--voxel", rec),
    C("register-voxel-negative", "capture register rec --voxel -0.01", "--voxel", rec),
    C("register-max-depth-zero", "capture register rec --max-depth 0", "--max-depth", rec),
    C("register-tsdf-voxel-zero", "capture register rec --tsdf-voxel 0", "--tsdf-voxel", rec),
    C("register-loop-gaps-garbage", "capture register rec --loop-gaps a,b", "--loop-gaps", rec),
    C("register-loop-gaps-negative", "capture register rec --loop-gaps=-3", "--loop-gaps", rec),
    C("register-camera-unknown", "capture register rec --camera nosuch", "nosuch", rec),
    C("register-seed-negative", "capture register rec --seed -1", "--seed", rec),
    C("register-recording-missing", "capture register nowhere", "nowhere"),
    C("register-not-a-recording", "capture register obj", "obj", obj),
    C("register-colour-truncated", "capture register rec", "000001.png", lambda w: (rec(w), w.truncate(COLOR1))),
    # capture view
    C("view-rrd-a-folder", "capture view rec --rrd mine", "mine", lambda w: (rec(w), w.folder())),
    C("view-rrd-a-user-file", "capture view rec --rrd notes.txt", "notes.txt", lambda w: (rec(w), w.file("notes.txt"))),
    C("view-rrd-under-a-file", "capture view rec --rrd notes.txt/v.rrd", "notes.txt",
      lambda w: (rec(w), w.file("notes.txt"))),
    C("view-rrd-inside-the-recording", "capture view rec --rrd rec/view.rrd", "rec", rec),
    C("view-colour-zero-size", "capture view rec --rrd v.rrd", "000001.png", lambda w: (rec(w), w.truncate(COLOR1, 0))),
    C("view-every-zero", "capture view rec --rrd v.rrd --every 0", "--every", rec),
    C("view-recording-missing", "capture view nowhere --rrd v.rrd", "nowhere"),
    # capture board and calibrate
    C("board-squares-garbage", "capture board --out b --squares big", "--squares"),
    C("board-squares-one", "capture board --out b --squares 1x1", "--squares"),
    C("board-square-mm-zero", "capture board --out b --square-mm 0", "--square-mm"),
    C("board-marker-larger-than-square", "capture board --out b --marker-mm 40", "--marker-mm"),
    C("board-dpi-zero", "capture board --out b --dpi 0", "--dpi"),
    C("board-dictionary-unknown", "capture board --out b --dictionary NOPE", "NOPE"),
    C("board-out-user-folder", "capture board --out mine", "mine", lambda w: w.folder()),
    C("board-out-a-file", "capture board --out notes.txt", "notes.txt", lambda w: w.file("notes.txt")),
    C("calibrate-recording-missing", "capture calibrate nowhere", "nowhere"),
    C("calibrate-board-missing", "capture calibrate rig --board nope.json", "nope.json", lambda w: w.rec("rig", "rig")),
    C("calibrate-board-corrupt", "capture calibrate rig --board board.json", "board.json",
      lambda w: (w.rec("rig", "rig"), w.file("board.json", "{"))),
    C("calibrate-frame-out-of-range", "capture calibrate rig --frame 5", "--frame", lambda w: w.rec("rig", "rig")),
    C("calibrate-frame-negative", "capture calibrate rig --frame -1", "--frame", lambda w: w.rec("rig", "rig")),
    # compare
    C("compare-object-missing", "compare --object nowhere --real rec" + M, "nowhere", rec),
    C("compare-real-missing", "compare --object obj --real nowhere" + M, "nowhere", obj),
    C("compare-real-not-given", "compare --object obj" + M, "--real", obj),
    C("compare-model-garbage", "compare --object obj --real rec --model bad.pt", "bad.pt",
      lambda w: (obj(w), rec(w), w.garbage_model())),
    C("compare-object-stl-truncated", "compare --object obj --real rec" + M, "link2.stl",
      lambda w: (obj(w), rec(w), w.truncate("obj/link2.stl"))),
    C("compare-rrd-a-folder", "compare --object obj --real rec --rrd mine" + M, "mine",
      lambda w: (obj(w), rec(w), w.folder())),
    C("compare-rrd-a-user-file", "compare --object obj --real rec --rrd notes.txt" + M, "notes.txt",
      lambda w: (obj(w), rec(w), w.file("notes.txt"))),
    C("compare-sim-out-is-the-real-recording", "compare --object obj --real rec --sim-out rec" + M, "rec",
      lambda w: (obj(w), rec(w))),
    C("compare-sim-out-is-the-object", "compare --object obj --real rec --sim-out obj" + M, "obj",
      lambda w: (obj(w), rec(w))),
    C("compare-sim-out-user-folder", "compare --object obj --real rec --sim-out mine" + M, "mine",
      lambda w: (obj(w), rec(w), w.folder())),
    C("compare-batch-missing", "compare --batch nowhere --out t" + M, "nowhere"),
    C("compare-batch-out-user-folder", "compare --batch pairs --out mine" + M, "mine|pairs",
      lambda w: (w.empty("pairs"), w.folder())),
    # demo
    C("demo-out-user-folder", "demo --out mine", "mine", lambda w: w.folder()),
    C("demo-out-user-object-folder", "demo --out mine", "mine", lambda w: w.folder("mine/object")),
    C("demo-out-dot", "demo --out .", "--out|current"),
    C("demo-out-a-file", "demo --out notes.txt", "notes.txt", lambda w: w.file("notes.txt")),
    C("demo-model-missing", "demo --out d --model nope.pt", "nope.pt"),
    # bench and noise
    C("bench-dataset-instances-zero", "bench dataset --instances 0 --frames 1", "--instances"),
    C("bench-dataset-workers-garbage", "bench dataset --workers a,b --frames 1", "--workers"),
    C("bench-dataset-frames-zero", "bench dataset --instances 1 --frames 0", "--frames"),
    C("bench-capture-gaps-garbage", "bench capture --gaps x", "--gaps"),
    C("bench-capture-data-missing", "bench capture --data nowhere", "nowhere"),
    C("bench-nets-iters-zero", "bench nets --iters 0" + M, "--iters"),
    C("bench-nets-batch-sizes-garbage", "bench nets --batch-sizes x" + M, "--batch-sizes"),
    C("bench-object-repeats-zero", "bench object --repeats 0", "--repeats"),
    C("bench-sim2real-objects-zero", "bench sim2real --out b --objects 0", "--objects"),
    C("bench-sim2real-out-user-folder", "bench sim2real --out mine --objects 1", "mine", lambda w: w.folder()),
    C("noise-fit-source-missing", "noise fit nowhere --out n", "nowhere"),
    C("noise-fit-out-user-folder", "noise fit --out mine", "mine", lambda w: w.folder()),
]
# fmt: on


# -- running a case --------------------------------------------------------------------------------


def tree_changes(before: dict[str, str], after: dict[str, str]) -> list[str]:
    lost = sorted(set(before) - set(after))
    changed = sorted(k for k in set(before) & set(after) if before[k] != after[k])
    added = sorted(set(after) - set(before))
    out = []
    if lost or changed:
        out.append(f"DATA LOSS: removed {lost[:4]} changed {changed[:4]}")
    if added:
        out.append(f"LEFTOVER: added {added[:4]}{' ...' if len(added) > 4 else ''}")
    return out


class Overran(BaseException):
    """The case was accepted and kept working past its budget."""


@contextlib.contextmanager
def time_budget(seconds: float):
    def fire(signum, frame):
        raise Overran

    old = signal.signal(signal.SIGALRM, fire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def judge(case: Case, code, stderr: str, before: dict, after: dict, crash: str | None) -> list[str]:
    """What is wrong with a bad-input run (empty: it was refused as it should be)."""
    problems = []
    if crash:
        problems.append(crash)
    elif code == 0:
        problems.append("ACCEPTED: exit 0")
    lines = stderr_lines(stderr)
    if not crash and len(lines) > 1:
        problems.append(f"STDERR: {len(lines)} lines: {' | '.join(ln[:90] for ln in lines[:3])}")
    message = lines[-1] if lines else ""
    if not crash and code not in (None, 0):
        if not case.named_in(message):
            problems.append(f"MESSAGE does not name {case.names!r}: {message!r}")
        for word in case.forbid:
            if word in message:
                problems.append(f"MISLEADING {word!r}: {message!r}")
    problems += tree_changes(before, after)
    return problems


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_bad_input(case, sources, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    w = W(tmp_path, sources)
    argv = case.argv(w)
    capsys.readouterr()
    before = tree(tmp_path)
    crash = code = None
    try:
        with time_budget(case.budget_s):
            code = main(argv)
    except Overran:
        crash = f"ACCEPTED: still working after {case.budget_s:.0f} s"
    except SystemExit as exc:  # argparse
        code = exc.code
    except BaseException as exc:  # every exception that escapes is a traceback for the user
        crash = f"TRACEBACK {type(exc).__name__}: {str(exc).splitlines()[0][:160] if str(exc) else ''}"
    _, err = capsys.readouterr()
    problems = judge(case, code, err, before, tree(tmp_path), crash)
    if os.environ.get("SPARE_TWIN_BAD_INPUT_REPORT"):  # one JSON line per case, for triage
        with open(os.environ["SPARE_TWIN_BAD_INPUT_REPORT"], "a") as f:
            f.write(
                json.dumps({"id": case.id, "argv": argv, "code": code, "stderr": err[-400:], "problems": problems})
                + "\n"
            )
    assert not problems, f"spare-twin {' '.join(argv)}: " + "; ".join(problems)


# -- compare: refused before torch is loaded -------------------------------------------------------


def test_compare_refuses_before_torch_is_loaded(printed_object, rig_rec, tmp_path):
    """A missing input, a missing checkpoint or an output that is not compare's: said before the
    comparison's modules (torch and the stages: 5 s of a new process) are imported, and nothing written."""
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("mine")
    (tmp_path / "notes.txt").write_text("mine")
    for side in ("object", "real"):
        (tmp_path / "pairs" / "a" / side).mkdir(parents=True)
    cases = [
        (["--object", "nope", "--real", "nope2"], ("nope", "not a folder")),
        (["--object", "{obj}", "--real", "nope"], ("nope", "not a folder")),
        (["--object", "{obj}"], ("--real",)),
        (["--object", "{obj}", "--real", "{rec}", "--model", "nope.pt"], ("nope.pt", "no such checkpoint")),
        (["--object", "{obj}", "--real", "{rec}", "--sim-out", "mine"], ("mine", "--force")),
        (["--object", "{obj}", "--real", "{rec}", "--rrd", "notes.txt"], ("notes.txt", "--force")),
        (["--object", "{obj}", "--real", "{rec}", "--sim-out", "{obj}"], ("is the input",)),
        (["--batch", "nope", "--out", "t"], ("--batch nope",)),
        (["--batch", "pairs", "--out", "mine"], ("mine", "--force")),
    ]
    rec = Path(rig_rec.root)
    formatted = [
        (["compare", *[a.format(obj=printed_object.root, rec=rec) for a in argv]], words) for argv, words in cases
    ]
    refused_before_torch(formatted, tmp_path)
    assert not rec.with_name(rec.name + "_sim_twin").exists()


# -- through the console script --------------------------------------------------------------------

SUBPROCESS_CASES = [
    "object-seed-negative",
    "object-out-dot",
    "render-out-is-the-object",
    "dataset-seed-negative",
    "import-colour-zero-size",
    "view-rrd-a-folder",
    "object-config-lengths-string",
]


def run_script(argv: list[str], cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    return subprocess.run([str(SCRIPT), *argv], cwd=cwd, capture_output=True, text=True, timeout=timeout, env=env)


@pytest.mark.parametrize("case_id", SUBPROCESS_CASES)
def test_bad_input_console_script(case_id, sources, tmp_path):
    case = next(c for c in CASES if c.id == case_id)
    w = W(tmp_path, sources)
    with contextlib.chdir(tmp_path):
        argv = case.argv(w)
    before = tree(tmp_path)
    p = run_script(argv, tmp_path)
    crash = None
    if "Traceback (most recent call last)" in p.stderr:
        crash = f"TRACEBACK {stderr_lines(p.stderr)[-1][:160]}"
    elif p.returncode < 0:
        crash = f"KILLED by signal {-p.returncode}"
    problems = judge(case, p.returncode, p.stderr, before, tree(tmp_path), crash)
    assert not problems, f"spare-twin {' '.join(argv)} (exit {p.returncode}): " + "; ".join(problems)


# -- --json: one JSON object on stdout, whatever the libraries print -------------------------------

#: Inputs on which Open3D and pybullet have things to say.
NATURAL_JSON = {
    "object": ("object --links 2 --seed 1 --out o --json", lambda w: None),
    # a tiny recording: RANSAC on a few hundred points finds too few correspondences
    "capture-register-tiny": ("capture register rec --loop-gaps 2 --global-init always --json", rec),
    # two real frames with no poses: predict registers them itself
    "predict-real-frames": (
        "predict real --json" + MP,
        lambda w: main(
            ["capture", "import", w.copy("tum", "raw"), "--layout", "tum", "--intrinsics", TUM_K, "--out", "real"]
        ),
    ),
    # pybullet cannot read the mesh and says so on stdout
    "compare-truncated-mesh": (
        "compare --object obj --real rec --json" + M,
        lambda w: (obj(w), rec(w), w.truncate("obj/link2.stl")),
    ),
}


@pytest.mark.parametrize("name", list(NATURAL_JSON))
def test_json_stdout_on_inputs_that_make_libraries_talk(name, sources, tmp_path):
    args, setup = NATURAL_JSON[name]
    with contextlib.chdir(tmp_path):
        argv = Case(name, args, "", setup).argv(W(tmp_path, sources))
    p = run_script(argv, tmp_path, timeout=300)
    assert "Traceback" not in p.stderr, stderr_lines(p.stderr)[-1]
    if p.returncode == 0:
        lines = p.stdout.splitlines()
        assert len(lines) == 1 and isinstance(json.loads(lines[0]), dict), f"stdout: {p.stdout[:600]!r}"
    else:
        assert p.stdout == "", f"exit {p.returncode}, yet stdout holds {p.stdout[:600]!r}"


NOISY_LIBRARY = textwrap.dedent(
    """
    import ctypes, importlib, os, sys
    from spare_twin.cli import main

    module, name = sys.argv[1].split(":")
    mod = importlib.import_module(module)
    real = getattr(mod, name)
    libc = ctypes.CDLL(None)

    def noisy(*args, **kwargs):  # what Open3D's and pybullet's C++ code does: printf and write(1, ...)
        libc.printf(b"[Open3D WARNING] Too few correspondences\\n")
        os.write(1, b"b3Printf: injected\\n")
        print("python-level chatter")
        out = real(*args, **kwargs)
        libc.printf(b"[Open3D WARNING] after the work")
        return out

    setattr(mod, name, noisy)
    sys.exit(main(sys.argv[2:]))
    """
)

#: Each --json command, and the library function it calls to do its work.
INJECTED_JSON = {
    "object": ("spare_twin.object.folder:build_object", "object --links 1 --out o --no-preview --json", None),
    "predict": ("spare_twin.predict.run:predict_recording", "predict rec --json" + MP, rec),
    "capture-import": (
        "spare_twin.capture.importers:import_folder",
        "capture import src --layout 7scenes --out r --json",
        scenes,
    ),
    "capture-register": (
        "spare_twin.capture.pipeline:register_recording",
        "capture register r --object skip --loop-gaps 2 --json",
        lambda w: main(["capture", "import", scenes(w), "--layout", "7scenes", "--out", "r"]),
    ),
    "capture-view": ("spare_twin.capture.view:log_recording", "capture view rec --rrd v.rrd --json", rec),
    "evaluate": ("spare_twin.nets.evaluate:evaluate", "evaluate --data syn --json" + M, syn),
}


@pytest.mark.parametrize("name", list(INJECTED_JSON))
def test_json_stdout_whatever_c_libraries_print(name, sources, tmp_path):
    target, args, setup = INJECTED_JSON[name]
    with contextlib.chdir(tmp_path):
        argv = Case(name, args, "", setup or (lambda w: None)).argv(W(tmp_path, sources))
    p = subprocess.run(
        [sys.executable, "-c", NOISY_LIBRARY, target, *argv], cwd=tmp_path, capture_output=True, text=True, timeout=300
    )
    assert p.returncode == 0, stderr_lines(p.stderr)[-1:]
    assert "Too few correspondences" in p.stdout + p.stderr, f"{target} was not called: the test needs updating"
    lines = p.stdout.splitlines()
    assert len(lines) == 1 and isinstance(json.loads(lines[0]), dict), f"stdout: {p.stdout[:600]!r}"


def test_the_table_covers_every_command():
    ids = {c.id.split("-")[0] for c in CASES}
    commands = {"object", "render", "dataset", "train", "evaluate", "predict", "compare", "demo", "bench", "noise"}
    assert commands | {"import", "register", "view", "board", "calibrate"} <= ids
    assert len(CASES) >= 60 and len({c.id for c in CASES}) == len(CASES)
