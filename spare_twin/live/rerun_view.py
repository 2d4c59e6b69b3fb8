"""`live`'s view in Rerun: a spawned viewer, a running one (`connect`) or an `.rrd` file.

Entity layout (timeline `stream_time`: seconds of the stream)::

    world                       the stream's world: the first placed frame's camera (x right, y down)
    world/camera                the current camera: its pose and pinhole; world/camera/image its colour
    world/path                  the camera's path so far
    world/points                the placed frames' points, fused (thinned to `MAX_POINTS`)
    world/chain                 the estimate's chain, drawn in the points (base to tip, metres)
    twin<k>/<robot>             the printed twin's URDF through Rerun's URDF support (`live.rerun_twin`),
                                posed with the estimated joint angles; built from the estimate
                                (`object.folder.build_sim_twin`) unless an object folder is given
    estimate/n_links            the count, a time series
    estimate/length_pu/L<i>     the lengths (paper units) as time series
    estimate/answer             the latest answer in words
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from spare_twin.config import ChainSpec
from spare_twin.errors import SpareTwinError
from spare_twin.live.rerun_twin import UrdfTwin, chain_points_m
from spare_twin.object.folder import build_sim_twin, load_object
from spare_twin.output import RRD, writing

#: Fused points shown at most (a random, seeded thinning beyond).
MAX_POINTS = 150_000
#: The fused points are logged again after this many placed frames (and at every update): each
#: logging sends them all, so logging them every frame made a 10 s stream's .rrd 120 MB.
POINTS_EVERY = 10
#: A twin built from the estimate is built again when the count changes or a length moves this much (pu).
REBUILD_PU = 0.03
#: Colours of a twin built from the estimate, base first (it has no colours of its own).
TWIN_COLOURS = ("white", "orange", "blue", "green", "red", "yellow", "indigo")
TIMELINE = "stream_time"


def _blueprint():
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="/", name="camera path, fused points, estimated chain, posed twin"),
            rrb.Vertical(
                rrb.Spatial2DView(origin="world/camera", name="current frame"),
                rrb.TimeSeriesView(origin="estimate/n_links", name="count"),
                rrb.TimeSeriesView(origin="estimate/length_pu", name="lengths (paper units)"),
                rrb.TextDocumentView(origin="estimate/answer", name="answer"),
                row_shares=[3, 2, 2, 2],
            ),
            column_shares=[3, 2],
        ),
        rrb.TimePanel(timeline=TIMELINE, play_state="following"),
        collapse_panels=True,
    )


class LiveView:
    """The Rerun stream `live` logs to; `show_frame` and `show_update` are called from two threads
    (Rerun's time is per thread)."""

    def __init__(self, stream, ctx=None, object_dir: str | Path | None = None):
        import rerun as rr

        self.stream, self._viewer_scope = stream, ctx
        self._points: list[np.ndarray] = []
        self._n_points = 0
        self._since_logged = 0
        self._twins: list[tuple[UrdfTwin, tuple | None]] = []
        self._workdir = tempfile.TemporaryDirectory(prefix="spare-twin-live-")
        self.object = load_object(object_dir) if object_dir is not None else None
        stream.log("/", rr.ViewCoordinates.RDF, static=True)

    @classmethod
    def open(
        cls, rrd: str | Path | None = None, connect: str | None = None, object_dir=None, force: bool = False
    ) -> LiveView:
        """A view saved to `rrd`, sent to `connect`, or in a spawned viewer."""
        import rerun as rr

        stream = rr.RecordingStream("spare-twin-live")
        ctx = None
        if rrd is not None:
            ctx = writing(rrd, RRD, (), force)
            stream.save(ctx.__enter__(), default_blueprint=_blueprint())
        elif connect is not None:
            try:
                stream.connect_grpc(connect, default_blueprint=_blueprint())
            except Exception as exc:  # a malformed address: Rerun's own words, on one line
                raise SpareTwinError(f"connect {connect!r}: {' '.join(str(exc).split())}") from None
        else:
            stream.spawn(default_blueprint=_blueprint())
        return cls(stream, ctx, object_dir)

    def _at(self, t_s: float) -> None:
        self.stream.set_time(TIMELINE, duration=float(t_s))

    def show_frame(self, f, placed, tracker) -> None:
        """The current frame and, once placed, the camera there, its path and the frame's points."""
        import rerun as rr

        self._at(f.t_s)
        if placed is None:
            return
        fr, T = placed.frame, placed.T_world_camera
        self.stream.log("world/camera", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
        h, w = fr.depth_u16.shape
        self.stream.log(
            "world/camera", rr.Pinhole(image_from_camera=fr.K, width=w, height=h, image_plane_distance=0.05)
        )
        self.stream.log("world/camera/image", rr.Image(fr.color))
        centres = np.array([P[:3, 3] for P in tracker.path])
        self.stream.log("world/path", rr.LineStrips3D([centres], colors=[[255, 200, 0]], radii=0.001))
        self._add_points(fr, T)

    def _add_points(self, fr, T) -> None:
        step = 4  # every 4th pixel each way: plenty to see the object grow
        d = fr.depth_u16[::step, ::step].astype(np.float32) * np.float32(fr.depth_scale)
        v, u = np.nonzero((d > 0) & (d < 1.5))
        z = d[v, u]
        x = (u * step - fr.K[0, 2]) / fr.K[0, 0] * z
        y = (v * step - fr.K[1, 2]) / fr.K[1, 1] * z
        pts = np.stack([x, y, z], 1) @ T[:3, :3].T + T[:3, 3]
        rgb = fr.color[::step, ::step][v, u]
        self._points.append(np.concatenate([pts.astype(np.float32), rgb.astype(np.float32)], 1))
        self._n_points += len(pts)
        if self._n_points > MAX_POINTS:  # thin what is there by half, seeded: the same stream shows the same
            allp = np.concatenate(self._points)
            keep = np.random.default_rng(len(allp)).permutation(len(allp))[: MAX_POINTS // 2]
            self._points, self._n_points = [allp[np.sort(keep)]], MAX_POINTS // 2
        self._since_logged += 1
        if self._since_logged >= POINTS_EVERY:
            self._log_points()

    def _log_points(self) -> None:
        import rerun as rr

        if self._points:
            allp = np.concatenate(self._points)
            colors = allp[:, 3:].astype(np.uint8)
            self.stream.log("world/points", rr.Points3D(allp[:, :3], colors=colors, radii=0.0008))
        self._since_logged = 0

    def show_update(self, u, tracker) -> None:
        """An update: the chain, the time series, the answer in words and the posed twin."""
        import rerun as rr

        p = u.prediction
        self._at(u.t_s)
        self._log_points()
        words = "\n".join(["final: predict on the recording" if u.final else f"update at {u.t_s:.1f} s",
                           *p.in_words()])  # fmt: skip
        if u.enough:
            words = "**enough**\n\n" + words
        self.stream.log("estimate/answer", rr.TextDocument(words))
        if p.n_links is None:
            return
        self.stream.log("estimate/n_links", rr.Scalars(float(p.n_links)))
        for i, length in enumerate(p.link_lengths_pu):
            self.stream.log(f"estimate/length_pu/L{i}", rr.Scalars(float(length)))
        T = p.T_world_profile
        if T is None:
            return
        pts = chain_points_m(p.link_lengths_pu, p.joint_angles_rad, p.print_scale, p.parts.layer_pitch_mm / 1000.0)
        world = pts @ T[:3, :3].T + T[:3, 3]
        self.stream.log("world/chain", rr.LineStrips3D([world], colors=[[255, 40, 40]], radii=0.002))
        twin = self._twin_for(p, u.t_s)
        if twin is not None and p.joint_angles_rad is not None and twin.n_joints == len(p.joint_angles_rad):
            twin.pose(T, p.joint_angles_rad)

    def _new_twin(self, urdf_path: Path, name: str, t_s: float) -> UrdfTwin:
        twin = UrdfTwin(self.stream, urdf_path, name)
        self._at(0.0)
        twin.hide()  # until its first pose: its root is placed nowhere before
        self._at(t_s)
        return twin

    def _twin_for(self, p, t_s: float) -> UrdfTwin | None:
        """The twin to pose: the object folder's, else the one built from the estimate, built again
        when the estimate moved on (`REBUILD_PU`)."""
        if self.object is not None:
            if not self._twins:
                self._twins.append((self._new_twin(self.object.urdf_path, "twin0", t_s), None))
            return self._twins[0][0]
        key = (p.n_links, tuple(p.link_lengths_pu))
        if self._twins:
            twin, built = self._twins[-1]
            if built[0] == key[0] and np.max(np.abs(np.subtract(built[1], key[1]))) <= REBUILD_PU:
                return twin
        try:
            spec = ChainSpec(p.n_links, key[1], TWIN_COLOURS[: p.n_links + 1], print_scale=p.print_scale,
                             name=f"twin{len(self._twins)}")  # fmt: skip
            folder = build_sim_twin(spec, Path(self._workdir.name) / spec.name)
        except SpareTwinError:  # lengths no printable chain has: no twin for this estimate
            return self._twins[-1][0] if self._twins else None
        if self._twins:
            self._twins[-1][0].hide()
        twin = self._new_twin(folder.urdf_path, spec.name, t_s)
        self._twins.append((twin, key))
        return twin

    def close(self) -> None:
        """Flush; an .rrd is put in place whole."""
        self.stream.flush()
        self.stream.disconnect()
        if self._viewer_scope is not None:
            self._viewer_scope.__exit__(None, None, None)
            self._viewer_scope = None
        self._workdir.cleanup()

    def abandon(self) -> None:
        """After an error: an .rrd being written is dropped, what was at its place stays."""
        if self._viewer_scope is not None:
            self.stream.disconnect()
            err = SpareTwinError("live stopped")
            self._viewer_scope.__exit__(SpareTwinError, err, None)
            self._viewer_scope = None
