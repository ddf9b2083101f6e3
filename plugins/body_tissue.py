"""``body-tissue``: a radio material for the human body (Sionna RT 2.2 plugin).

.. _plugin-bsdf-body-tissue:

Body tissue (:monosp:`body-tissue`)
-------------------------------------

A homogeneous, lossy dielectric for people walking through a scene. It is a
:class:`sionna.rt.RadioMaterial` (ITU-R P.2040 single-layer slab model), so
reflection, refraction and diffuse scattering off a body follow the same
physics as every other Sionna material. The defaults are the values quoted for
the body at 2.4 GHz in the paper this project follows (relative permittivity
about 40; conductivity 1.7 S/m, close to Gabriel et al.'s muscle/skin data at
2.4 GHz). The values do **not** change with the scene's frequency: set them for
another carrier.

.. list-table::
   :header-rows: 1

   * - Parameter
     - Type
     - Description
   * - relative_permittivity
     - float
     - Real relative permittivity :math:`\\varepsilon_r` (unitless, >= 1). Default: 40.0
   * - conductivity
     - float
     - Conductivity :math:`\\sigma` in S/m (>= 0). Default: 1.7
   * - thickness
     - float
     - Slab thickness in metres used by the slab model at each face a ray meets.
       Default: 0.2 (a torso; the field decays by :math:`1/e` within about 2 cm, so
       any value above a few centimetres gives the same reflection)
   * - scattering_coefficient
     - float
     - Diffuse scattering coefficient :math:`S \\in [0, 1]`. Default: 0.0
   * - xpd_coefficient
     - float
     - Cross-polarisation discrimination :math:`K_x \\in [0, 1]`. Default: 0.0
   * - color
     - rgb
     - Colour in previews (not radio). Default: (0.87, 0.67, 0.55)

The complex relative permittivity is
:math:`\\eta = \\varepsilon_r - j\\,\\sigma / (\\omega \\varepsilon_0)`; at 2.4 GHz the
defaults give :math:`\\eta \\approx 40 - 12.73j`.

Example (the plugin must be registered first: ``rfmitsuba.plugins.register()``):

.. code-block:: xml

    <bsdf type="body-tissue" id="tissue">
        <float name="relative_permittivity" value="40.0"/>
        <float name="conductivity" value="1.7"/>
        <float name="thickness" value="0.2"/>
    </bsdf>
    <shape type="ply" id="person">
        <string name="filename" value="meshes/person.ply"/>
        <ref id="tissue" name="bsdf"/>
    </shape>

From Python: ``BodyTissueMaterial(name="tissue", relative_permittivity=40.0, conductivity=1.7)``.
"""
from __future__ import annotations

from rfmitsuba.core import backend

backend.variant()  # Sionna's classes bind to the active Mitsuba variant when imported

import mitsuba as mi  # noqa: E402
import sionna.rt  # noqa: E402,F401  (registers Sionna's own materials)
from sionna.rt import RadioMaterial  # noqa: E402

#: Plugin name used in XML: ``<bsdf type="body-tissue">``.
PLUGIN_NAME = "body-tissue"
#: The name scene XML written before used for the same material (it still loads).
OLD_PLUGIN_NAME = "human-tissue"
DEFAULT_RELATIVE_PERMITTIVITY = 40.0   # unitless, at 2.4 GHz
DEFAULT_CONDUCTIVITY = 1.7             # S/m, at 2.4 GHz
DEFAULT_THICKNESS = 0.2                # m
DEFAULT_COLOR = (0.87, 0.67, 0.55)


class BodyTissueMaterial(RadioMaterial):
    """Radio material of body tissue (see the module docstring for parameters and units).

    Either ``props`` (from XML) or ``name`` must be given.
    """

    def __init__(self, name: str | None = None, *, relative_permittivity: float = DEFAULT_RELATIVE_PERMITTIVITY,
                 conductivity: float = DEFAULT_CONDUCTIVITY, thickness: float = DEFAULT_THICKNESS,
                 scattering_coefficient: float = 0.0, xpd_coefficient: float = 0.0,
                 color: tuple[float, float, float] = DEFAULT_COLOR, props: mi.Properties | None = None):
        if props is None:
            if name is None:
                raise ValueError("BodyTissueMaterial needs a name (or Mitsuba props)")
            super().__init__(name=name, thickness=thickness, relative_permittivity=relative_permittivity,
                             conductivity=conductivity, scattering_coefficient=scattering_coefficient,
                             xpd_coefficient=xpd_coefficient, color=color)
            return
        defaults = {"relative_permittivity": DEFAULT_RELATIVE_PERMITTIVITY,
                    "conductivity": DEFAULT_CONDUCTIVITY, "thickness": DEFAULT_THICKNESS}
        for key, value in defaults.items():
            if key not in props:
                props[key] = value
        if not any(k in props for k in ("color", "reflectance", "base_color")):
            props["color"] = mi.ScalarColor3f(DEFAULT_COLOR)
        super().__init__(props=props)

    def to_string(self) -> str:
        return (f"BodyTissueMaterial eta_r={self.relative_permittivity[0]:.3f} "
                f"sigma={self.conductivity[0]:.3f} S/m thickness={self.thickness[0]:.3f} m")


def register() -> None:
    """Register ``body-tissue`` with Mitsuba for the active variant (call via :func:`rfmitsuba.plugins.register`)."""
    for name in (PLUGIN_NAME, OLD_PLUGIN_NAME):
        mi.register_bsdf(name, lambda props: BodyTissueMaterial(props=props))
