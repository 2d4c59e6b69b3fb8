"""Property tests (hypothesis): random and mutated chain configurations and recordings fed to the loaders.

Each input is either accepted, and then round-trips (a configuration through its dict and its JSON file;
a recording through a rewrite with `RecordingWriter`), or refused with a one-line `SpareTwinError`.
Anything else (another exception, a multi-line message) is a bug. Runs are derandomised and keep no
example database, so CI sees the same examples every time.
"""

from __future__ import annotations

import json
import math
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from spare_twin.config import COLORS, ChainSpec, sample_chain
from spare_twin.errors import SpareTwinError
from spare_twin.io import encode_png
from spare_twin.recording import Recording, RecordingWriter

SETTINGS = settings(
    max_examples=60,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)

JSON_SCALARS = (
    st.none()
    | st.booleans()
    | st.integers(-(2**40), 2**40)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=8)
)
JSON_VALUES = st.recursive(
    JSON_SCALARS,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=8,
)
#: Values that look almost right: the kinds of slip a hand-written file has.
NEAR_MISSES = st.sampled_from(
    [0, -1, 1.5, -0.0, 1e308, math.nan, math.inf, "", "3", "three", None, True, [], {}, [1], "red", 7, 2**63]
)


def refused_cleanly(exc: SpareTwinError) -> None:
    message = str(exc)
    assert message and "\n" not in message and "Traceback" not in message, repr(message)


# -- chain configurations --------------------------------------------------------------------------


def check_chain(d) -> ChainSpec | None:
    """Accepted: the spec, after checking its round trips. Refused: None, after checking the message."""
    try:
        spec = ChainSpec.from_dict(d, source="spec.json")
    except SpareTwinError as exc:
        refused_cleanly(exc)
        return None
    assert ChainSpec.from_dict(spec.to_dict()) == spec
    assert ChainSpec.from_dict(json.loads(spec.to_json())) == spec
    assert spec.to_json() == ChainSpec.from_dict(json.loads(spec.to_json())).to_json()
    assert 1 <= spec.n_links <= 6 and len(spec.link_lengths_pu) == spec.n_links + 1
    assert all(math.isfinite(x) and x > 0 for x in spec.link_lengths_pu) and set(spec.colors) <= set(COLORS)
    return spec


KEYS = ["n_links", "link_lengths_pu", "colors", "print_scale", "name", "seed", "parts", "printer", "format", "bogus"]


@SETTINGS
@given(st.dictionaries(st.sampled_from(KEYS), JSON_VALUES | NEAR_MISSES, max_size=8))
def test_random_chain_configurations(d):
    check_chain(d)


#: Top-level keys in the order hypothesis prefers them (it shrinks towards the first).
CHAIN_KEYS = ["link_lengths_pu", "n_links", "colors", "print_scale", "name", "seed", "parts", "printer"]
MUTATIONS = ["replace", "element", "grow", "shrink", "sub", "drop"]


@st.composite
def mutated_chains(draw) -> tuple[dict, list[str]]:
    """A valid object.json configuration with one to three slips in it, and the keys it slipped in."""
    d = sample_chain(draw(st.integers(1, 6)), seed=draw(st.integers(0, 50))).to_dict()
    touched = []
    for _ in range(draw(st.integers(1, 3))):
        key = draw(st.sampled_from([k for k in CHAIN_KEYS if k in d] or ["bogus"]))
        how = draw(st.sampled_from(MUTATIONS))
        value = draw(NEAR_MISSES | JSON_VALUES)
        touched.append(key)
        if how == "drop":
            d.pop(key, None)
        elif how == "replace":
            d[key] = value
        elif isinstance(d.get(key), list) and d[key]:
            items = list(d[key])
            i = draw(st.integers(0, len(items) - 1))
            if how == "element":
                items[i] = value
            elif how == "grow":
                items.insert(i, items[i])
            else:
                items.pop(i)
            d[key] = items
        elif isinstance(d.get(key), dict) and d[key]:
            sub = dict(d[key])
            sub[draw(st.sampled_from(sorted(sub) + ["bogus_mm"]))] = value
            d[key] = sub
    return d, touched


@settings(SETTINGS, max_examples=150)
@given(mutated_chains())
def test_mutated_chain_configurations(mutated):
    """A refusal of a single slip names the key it is in (not just a Python type error)."""
    d, touched = mutated
    try:
        ChainSpec.from_dict(d, source="spec.json")
    except SpareTwinError as exc:
        if len(touched) == 1 and touched[0] not in ("parts", "printer"):
            assert touched[0] in str(exc), f"{touched[0]} slipped; the message says {str(exc)!r}"
    check_chain(d)


@SETTINGS
@given(st.integers(1, 6), st.integers(0, 2**32))
def test_sampled_chains_round_trip(n, seed):
    assert check_chain(sample_chain(n, seed=seed).to_dict()) == sample_chain(n, seed=seed)


@SETTINGS
@given(
    st.one_of(
        st.binary(max_size=64),
        mutated_chains().map(lambda m: json.dumps(m[0]).encode()),
        mutated_chains().map(lambda m: json.dumps(m[0]).encode()[: len(json.dumps(m[0])) // 2]),
    )
)
def test_configuration_files(data):
    """`object --config FILE` reads with ChainSpec.from_json_file: bytes of any kind, truncated JSON too."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "spec.json"
        path.write_bytes(data)
        try:
            spec = ChainSpec.from_json_file(path)
        except SpareTwinError as exc:
            refused_cleanly(exc)
            assert str(path) in str(exc)
            return
        path.write_text(spec.to_json())
        assert ChainSpec.from_json_file(path) == spec


# -- recordings ------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def base_recordings(printed_object, tmp_path_factory) -> dict[str, Path]:
    """Two tiny sim recordings: one hand-held camera with per-frame poses, and the 8-camera rig."""
    from spare_twin.sim.render import RenderConfig, render_recording

    root = tmp_path_factory.mktemp("property_recordings")
    render_recording(
        printed_object.root,
        root / "handheld",
        RenderConfig(frames=3, resolution="40x30", path="handheld", motion="static"),
        progress=False,
    )
    render_recording(
        printed_object.root,
        root / "rig",
        RenderConfig(frames=1, resolution="32x24", segmentation=False),
        progress=False,
    )
    return {"handheld": root / "handheld", "rig": root / "rig"}


def load_everything(root: Path) -> Recording:
    """What the commands read from a recording: metadata, every picture, poses, ground truth."""
    rec = Recording.open(root)
    rec.validate()
    _ = rec.fps, rec.depth_scale, rec.timestamps_s, rec.source, rec.registration, rec.ground_truth()
    for cam in rec.cameras:
        rec.camera_poses(cam.name)
        for f in range(rec.n_frames):
            rec.color(cam.name, f)
            rec.depth_m(cam.name, f)
            rec.segmentation(cam.name, f)
            rec.T_world_camera(cam.name, f)
    return rec


def rewrite(rec: Recording, out: Path) -> Recording:
    with RecordingWriter(
        out,
        rec.cameras,
        rec.n_frames,
        rec.fps,
        rec.source,
        depth_scale=rec.depth_scale,
        object_config=rec.object_config,
        rig=rec.rig,
        timestamps_s=[float(t) for t in rec.timestamps_s],
    ) as w:
        for cam in rec.cameras:
            for f in range(rec.n_frames):
                w.add_encoded(cam.name, f, rec.path(cam.name, "color", f).read_bytes(), rec.depth_raw(cam.name, f))
                if cam.poses == "per_frame":
                    w.set_pose(cam.name, f, rec.T_world_camera(cam.name, f))
    return Recording.open(out)


def check_recording(root: Path) -> None:
    try:
        rec = load_everything(root)
    except SpareTwinError as exc:
        refused_cleanly(exc)
        return
    again = rewrite(rec, root.parent / "again")
    assert again.n_frames == rec.n_frames and again.fps == rec.fps and again.depth_scale == rec.depth_scale
    assert [c.to_dict() for c in again.cameras] == [c.to_dict() for c in rec.cameras]
    assert np.array_equal(again.timestamps_s, rec.timestamps_s)
    for cam in rec.cameras:
        for f in range(rec.n_frames):
            assert np.array_equal(again.depth_raw(cam.name, f), rec.depth_raw(cam.name, f))
            assert np.array_equal(again.color(cam.name, f), rec.color(cam.name, f))
        poses = rec.camera_poses(cam.name)
        assert (poses is None) == (again.camera_poses(cam.name) is None)
        if poses is not None:
            assert np.array_equal(again.camera_poses(cam.name), poses)


def mutated_copy(base: Path, tmp: str, mutate) -> Path:
    root = Path(tmp) / "rec"
    shutil.copytree(base, root)
    mutate(root)
    return root


def edit_meta(root: Path, fn) -> None:
    p = root / "recording.json"
    meta = json.loads(p.read_text())
    fn(meta)
    p.write_text(json.dumps(meta))


META_KEYS = ["format", "version", "frames", "fps", "depth_scale", "timestamps_s", "source", "object", "rig",
             "cameras", "registration"]  # fmt: skip
CAMERA_KEYS = ["name", "width", "height", "K", "T_world_camera", "poses"]


@SETTINGS
@given(
    st.sampled_from(["handheld", "rig"]),
    st.lists(st.tuples(st.sampled_from(META_KEYS), st.booleans(), JSON_VALUES | NEAR_MISSES), min_size=1, max_size=3),
)
def test_mutated_recording_json(base_recordings, which, edits):
    def mutate(root):
        def fn(meta):
            for key, drop, value in edits:
                if drop:
                    meta.pop(key, None)
                else:
                    meta[key] = value

        edit_meta(root, fn)

    with tempfile.TemporaryDirectory() as tmp:
        check_recording(mutated_copy(base_recordings[which], tmp, mutate))


@SETTINGS
@given(
    st.sampled_from(["handheld", "rig"]),
    st.integers(0, 7),
    st.lists(st.tuples(st.sampled_from(CAMERA_KEYS), st.booleans(), JSON_VALUES | NEAR_MISSES), min_size=1, max_size=3),
)
def test_mutated_camera_entries(base_recordings, which, cam_index, edits):
    def mutate(root):
        def fn(meta):
            cam = meta["cameras"][cam_index % len(meta["cameras"])]
            for key, drop, value in edits:
                if drop:
                    cam.pop(key, None)
                else:
                    cam[key] = value

        edit_meta(root, fn)

    with tempfile.TemporaryDirectory() as tmp:
        check_recording(mutated_copy(base_recordings[which], tmp, mutate))


PNG_DAMAGE = ["zero-size", "truncated", "random-bytes", "wrong-size", "eight-bit", "sixteen-bit", "colour", "gone"]


@SETTINGS
@given(
    st.sampled_from(["handheld", "rig"]),
    st.sampled_from(["color", "depth", "segmentation"]),
    st.integers(0, 50),
    st.sampled_from(PNG_DAMAGE),
    st.floats(0.01, 0.99),
    st.binary(min_size=1, max_size=64),
)
def test_damaged_pictures(base_recordings, which, kind, pick, damage, fraction, noise):
    def mutate(root):
        files = sorted((root / "cameras").glob(f"*/{kind}/*.png")) or sorted((root / "cameras").glob("*/*/*.png"))
        p = files[pick % len(files)]
        data = p.read_bytes()
        rng = np.random.default_rng(pick)
        if damage == "zero-size":
            p.write_bytes(b"")
        elif damage == "truncated":
            p.write_bytes(data[: max(1, int(len(data) * fraction))])
        elif damage == "random-bytes":
            p.write_bytes(noise)
        elif damage == "wrong-size":
            p.write_bytes(encode_png(rng.integers(0, 255, (7, 9), dtype=np.uint8)))
        elif damage == "eight-bit":
            p.write_bytes(encode_png(rng.integers(0, 255, (30, 40), dtype=np.uint8)))
        elif damage == "sixteen-bit":
            p.write_bytes(encode_png(rng.integers(0, 65535, (30, 40), dtype=np.uint16)))
        elif damage == "colour":
            p.write_bytes(encode_png(rng.integers(0, 255, (30, 40, 3), dtype=np.uint8)))
        else:
            p.unlink()

    with tempfile.TemporaryDirectory() as tmp:
        check_recording(mutated_copy(base_recordings[which], tmp, mutate))


@SETTINGS
@given(
    st.sampled_from(["truncated", "wrong-shape", "not-finite", "text", "extra-frame"]),
    st.floats(0.05, 0.95),
)
def test_damaged_pose_files(base_recordings, damage, fraction):
    def mutate(root):
        p = root / "cameras" / "cam0" / "T_world_camera.npy"
        poses = np.load(p)
        if damage == "truncated":
            data = p.read_bytes()
            p.write_bytes(data[: int(len(data) * fraction)])
        elif damage == "wrong-shape":
            np.save(p, poses[:, :3, :])
        elif damage == "not-finite":
            poses[0, 0, 3] = np.nan
            np.save(p, poses)
        elif damage == "text":
            p.write_text("not numpy")
        else:
            np.save(p, np.concatenate([poses, poses[:1]]))

    with tempfile.TemporaryDirectory() as tmp:
        check_recording(mutated_copy(base_recordings["handheld"], tmp, mutate))


def test_untouched_recordings_round_trip(base_recordings, tmp_path):
    for name, base in base_recordings.items():
        shutil.copytree(base, tmp_path / name / "rec")
        check_recording(tmp_path / name / "rec")
