"""`live` from its options: the source, the estimator and the view opened and checked before
anything is written, then `live.session.run_live`."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from spare_twin.config import PartDims
from spare_twin.live.config import LiveConfig
from spare_twin.live.estimate import load_estimator
from spare_twin.live.rerun_view import LiveView
from spare_twin.live.session import LiveResult, Update, run_live
from spare_twin.live.sources import Source, open_live


def live(
    out: str | Path,
    replay: str | Path | None = None,
    bag: str | Path | None = None,
    speed: float = 1.0,
    rrd: str | Path | None = None,
    connect: str | None = None,
    viewer: bool = True,
    object_dir: str | Path | None = None,
    until_stable: bool = False,
    stable_s: float = 3.0,
    update_s: float = 1.0,
    views: int = 16,
    answer: str = "combined",
    model: str | Path | None = None,
    print_scale: float = 0.08,
    parts: PartDims | None = None,
    on_update: Callable[[Update], None] = lambda u: None,
    say: Callable[[str], None] = lambda line: None,
    force: bool = False,
    source: Source | None = None,
) -> LiveResult:
    """`spare-twin live`; see `live.session`. The view goes to `rrd` (a file), `connect` (a running
    viewer) or, with `viewer`, a spawned viewer; none without any of them. `parts`: what the chain was
    printed with (`predict --parts`). `source`: what `live.sources.open_live` opened with these
    outputs and this source (`spare-twin live` opens it before it imports this module), which this
    then owns and closes; None: opened here."""
    cfg = LiveConfig(update_s=update_s, stable_s=stable_s, until_stable=until_stable, views=views)
    if source is None:
        source = open_live(out, replay, bag, speed, rrd, connect, force)
    view = None
    try:
        est = load_estimator(model, answer, print_scale, parts)
        if rrd is not None or connect is not None or viewer:
            view = LiveView.open(rrd=rrd, connect=connect, object_dir=object_dir, force=force)
    except BaseException:
        source.close()
        raise
    try:
        res = run_live(source, out, est, cfg, on_update, say, view, force, wait_for_use=(speed == 0))
    except BaseException:
        if view is not None:
            view.abandon()
        raise
    if view is not None:
        view.close()
    return res
