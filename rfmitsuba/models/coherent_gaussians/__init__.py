"""The coherent Gaussian field: virtual sources and scatterers with complex gains, summed coherently
at the array's elements and read out by the Bartlett beamformer, for known and unknown rooms.

One concept per module:

* :mod:`.config`: :class:`CoherentGaussianConfig`, the architecture and initialisation options;
* :mod:`.geometry`: the data's geometry (how widely the positions spread) and the room's (a room
  box as reflections, reflections composed into image sources);
* :mod:`.scan`: the directional scan of the training PAS (:func:`scan`);
* :mod:`.array`: the array model (mutual coupling, pose) and the read-out;
* :mod:`.field`: :class:`CoherentGaussianField`, its parameters, channels and state (the physics
  is in that module's docstring);
* :mod:`.build`: the Stage-1 initial field from a dataset (:func:`initial_field`).
"""
from .array import coupling_index, coupling_size, read_out, summed_channels
from .build import initial_field
from .config import CoherentGaussianConfig
from .field import FORMAT, LR_GROUPS, CoherentGaussianField
from .geometry import (
    DEFAULT_VIS_GRID,
    compose_images,
    default_vis_grid,
    outside_room_box,
    position_spread_deg,
    room_box_planes,
    scan_planes,
    spreads_wide,
    uses_pursuit,
)
from .scan import pas_lookup, pas_pixels, scan

__all__ = ["CoherentGaussianConfig", "CoherentGaussianField", "DEFAULT_VIS_GRID", "FORMAT", "LR_GROUPS",
           "compose_images", "coupling_index", "coupling_size", "default_vis_grid", "initial_field",
           "outside_room_box", "pas_lookup", "pas_pixels", "position_spread_deg", "read_out", "room_box_planes",
           "scan", "scan_planes", "spreads_wide", "summed_channels", "uses_pursuit"]
