"""The one way the library imports open3d (`quiet_open3d`), where it needs it: never at module import.

Two things are done on the way in:
- its console messages are limited to errors: they go to stdout, which JSON output owns;
- its plotly viewer (`open3d.visualization.draw_plotly`) is loaded on first use instead of with
  open3d. open3d imports that module, and with it plotly and dash, whenever it is imported: 0.7-1.2 s
  of the 1.5-1.7 s that `import open3d` took on the 2-core machine, in every `capture`, `compare` and
  `live` command, for a viewer the project never opens.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import sys
import types

#: The open3d module that imports plotly and dash, and the names open3d's own package takes from it.
PLOTLY_VIEWER = "open3d.visualization.draw_plotly"
PLOTLY_VIEWER_NAMES = ("get_plotly_fig", "draw_plotly", "draw_plotly_server")


def quiet_open3d():
    """open3d, imported with its console messages limited to errors and its plotly viewer deferred."""
    if "open3d" not in sys.modules:
        _defer_plotly_viewer()
    import open3d as o3d

    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    return o3d


def _defer_plotly_viewer() -> None:
    """Stand in for `PLOTLY_VIEWER` until something uses it: then the real module is loaded, in its
    place in sys.modules, and the call or attribute goes to it (a user of the same process who opens
    open3d's plotly viewer gets the real one)."""
    if PLOTLY_VIEWER in sys.modules:
        return
    stand_in = types.ModuleType(PLOTLY_VIEWER, "open3d's plotly viewer, loaded on first use (spare_twin.open3d_loader)")

    def real() -> types.ModuleType:
        if sys.modules.get(PLOTLY_VIEWER) is not stand_in:
            return sys.modules[PLOTLY_VIEWER]
        package = sys.modules["open3d.visualization"]
        spec = importlib.machinery.PathFinder.find_spec(PLOTLY_VIEWER, package.__path__)
        module = importlib.util.module_from_spec(spec)
        sys.modules[PLOTLY_VIEWER] = module
        try:
            spec.loader.exec_module(module)
        except BaseException:
            sys.modules[PLOTLY_VIEWER] = stand_in
            raise
        for name in PLOTLY_VIEWER_NAMES:  # what open3d.visualization took from the stand-in
            if getattr(package, name, None) is getattr(stand_in, name, None):
                setattr(package, name, getattr(module, name))
        return module

    def deferred(name: str):
        def call(*args, **kwargs):
            return getattr(real(), name)(*args, **kwargs)

        call.__name__ = call.__qualname__ = name
        return call

    for name in PLOTLY_VIEWER_NAMES:
        setattr(stand_in, name, deferred(name))

    def other(name: str):
        if name.startswith("__"):  # the import system's questions (`__path__`: is it a package?)
            raise AttributeError(name)
        return getattr(real(), name)

    stand_in.__getattr__ = other  # any other name: the real module's
    sys.modules[PLOTLY_VIEWER] = stand_in
