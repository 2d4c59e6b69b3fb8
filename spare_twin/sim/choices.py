"""The choices a simulated capture is configured from: the renderers and the most clutter a scene
takes. Light to import (no renderer, no trimesh): configurations are checked against them before a
renderer is loaded (`bench.settings`, `sim.render`)."""

from __future__ import annotations

#: The renderers `spare-twin render --renderer` offers (`sim.raycast.make_renderer`).
RENDERERS = ("pybullet", "raycast")
#: Most clutter items one scene takes (more leave no room clear of the object on a 12..35 cm ring).
MAX_CLUTTER = 8
