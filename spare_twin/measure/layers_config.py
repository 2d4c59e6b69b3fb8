"""The layer measurement's settings (`LayersConfig`, metres): the printed parts' geometry that reads
the layers (their pitch, the plates, the socket) and the thresholds that count, fit and check the
chain (`measure.layers`, `measure.merges`). `LayersConfig.for_parts` gives another print's."""

from __future__ import annotations

from dataclasses import dataclass

from spare_twin.config import PartDims, min_between_axes_mm_of
from spare_twin.observe.profile import parts_geometry_m

#: Points this far above the socket's top are still the socket (its rim, noise).
SOCKET_MARGIN_M = 0.003
#: How far a measured link length may fall short of the printed one (the free ends come within 0.8 mm,
#: the links between joints within about 1 mm on hand-held captures).
LENGTH_ERROR_M = 0.0015
#: How far a measured free end (the last link's tip) may fall short of the printed one.
FREE_END_ERROR_M = 0.0008


def layers_geometry_m(parts: PartDims) -> dict[str, float]:
    """The measurement's settings that the printed parts set (metres), from the profile's
    (`observe.profile.parts_geometry_m`: the one place they are derived)."""
    g = parts_geometry_m(parts)
    return {
        "layer_pitch_m": g["layer_pitch_m"],
        "half_width_m": g["link_width_m"] / 2,
        "half_thickness_m": g["link_thickness_m"] / 2,
        "min_height_m": g["keepout_m"] + SOCKET_MARGIN_M,
        "min_middle_link_m": min_between_axes_mm_of(parts) / 1000.0 - LENGTH_ERROR_M,
        "min_last_link_m": g["link_width_m"] / 2 - FREE_END_ERROR_M,
    }


_DEFAULT_PARTS = layers_geometry_m(PartDims())


@dataclass(frozen=True)
class LayersConfig:
    """Measurement settings (metres). The plates' and the socket's are the default parts'
    (`config.PartDims`); `for_parts` gives another print's."""

    layer_pitch_m: float = _DEFAULT_PARTS["layer_pitch_m"]
    half_width_m: float = _DEFAULT_PARTS["half_width_m"]
    """Half a link plate's width: the plate is its centre line thickened by this."""
    min_height_m: float = _DEFAULT_PARTS["min_height_m"]
    """Points below this are the foot and the socket, not links."""
    radius_m: float = 0.006
    """Neighbourhood (in the chain's plane) whose median t labels a point."""
    half_thickness_m: float = _DEFAULT_PARTS["half_thickness_m"]
    """A plate's face lies this far from its centre across the plane (half its thickness)."""
    min_side_cosine: float = 0.3
    """A point whose cameras look at it this squarely along t is on a face, not an edge."""
    max_shear: float = 0.15
    """Largest shear of t along s (tan of the plane direction's error, about 8.5 deg) searched for."""
    shear_steps: int = 301
    shear_prior: float = 0.3
    """Coherence a shear must gain per unit of shear to be preferred to none (`_layer_shear`)."""
    min_layer_points: int = 12
    """A layer with fewer points is noise (flying pixels, a pin head), not a link."""
    min_layer_fraction: float = 0.03
    """... or fewer than this share of the links' points,"""
    min_thin_layer_width: float = 0.9
    """... unless it is the layer just above the others and its points span this share of a plate's
    width across their main direction (`count_links`): a top link seen in few points (dark plastic, a
    capture from far) still shows its plate's width, a strip of its parent read a layer up (flying
    pixels, a rim) does not."""
    coverage_tolerance_m: float = 0.0025
    """A plate sample this near a point of its layer is covered (about the points' spacing: set for
    the 3 mm merge measured until release 0.6.19, kept for the 2 mm one). Nothing else stops a free
    end (the base's top, the last link's tip) from running on past its points, since a longer plate
    leaves fewer points outside: at 3.5 mm the ends came out 1.5-3 mm long on hand-held captures."""
    max_stray_offset: float = 0.25
    """A top layer whose points' median plate centre is within this of its own layer is a link."""
    max_top_inside_parent: float = 0.8
    """A top layer with this share of its points on its parent's plate is the parent's (`merges.top_layer_is_stray`)."""
    cap_reach: float = 1.0
    """Coverage samples reach this share of a half width past the centre line's ends (to the
    rounded ends' rims)."""
    free_end_pull: float = 0.01
    """Pull on the two free ends' lengths (the base's top, the last link's tip), per metre and per
    root point: within the coverage tolerance nothing else holds them, and they drifted out (base
    +0.9 mm in the rig, last link +1.4-2.0 mm on hand-held captures). With it the fit keeps the
    shortest chain that holds the points; the free ends are within 0.8 mm either way."""
    max_rms_m: float = 0.01
    """Points farther than this (RMS, outside their plates) from the best chain are no chain to
    measure: a capture whose views are out of register blurs a chain into a cloud 2-3 cm thick. On
    well-registered captures the RMS stays below 9 mm (Kinect), 5 mm in the rig."""
    samples_per_link: int = 12
    follow_comb: bool = True
    """Read the layers a second way, the comb followed along the chain (`measure.plates`), and keep
    that reading where it holds one piece a layer and none past the last where the comb's does not
    (`split_layers`, `past_last_layer`), or fits clearly better (`ONE_COUNT_RMS_SHARE`); False: one comb of the layer
    pitch for the whole chain (the chain as designed, no play)."""
    min_middle_link_m: float = _DEFAULT_PARTS["min_middle_link_m"]
    """A link between two joints measured shorter than this (the shortest its parts can print,
    `config.min_between_axes_mm_of`, less `LENGTH_ERROR_M`) is no link: a plate tilted by the joints'
    play across the half-way mark between two layers (`merges.unprintable_link`)."""
    min_last_link_m: float = _DEFAULT_PARTS["min_last_link_m"]
    """A last link measured shorter than this (half a plate's width, the shortest `config.validate`
    prints, less `FREE_END_ERROR_M`) is no link: its parent's tip tilted by the joints' play into the
    layer above, which the fit can only cover with a link held at its lower bound (5 mm)
    (`merges.unprintable_link`)."""
    directions: int = 72
    """Link directions tried by the fit's second start (`fit._initial_sequential`)."""
    max_points: int = 3500
    """At most this many points are measured (evenly through their fixed order): a 2 mm merge of a
    hand-held capture (`observe.points.PointsConfig.fine_voxel_m`) holds 1,600-2,900 above the socket
    (six development captures), the rig's 96 x 128 views about 1,800."""
    bends: bool = True
    """Split the last layer where its points bend in the plane, two plates holding them far closer
    than its one (`measure.bends`); False: bends are not read."""
    joint_thickness: bool = True
    """Where the chain was seen from both sides of its plane, read its joints from how thick it stands
    there (`measure.joints`: a pin's overlap is two plates thick) before the plate centres' step."""

    @classmethod
    def for_parts(cls, parts: PartDims, **settings) -> LayersConfig:
        """The measurement of a chain printed with `parts` (its layer pitch, plates and socket);
        `settings` override the rest."""
        return cls(**{**layers_geometry_m(parts), **settings})
