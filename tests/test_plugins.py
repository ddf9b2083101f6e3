"""Tests of rfmitsuba.plugins (human-tissue): XML loading, documented values, closed-form Fresnel."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.constants import epsilon_0, pi

XML = """<scene version="2.1.0">
<bsdf type="human-tissue" id="tissue"/>
<bsdf type="human-tissue" id="tissue_wet">
  <float name="relative_permittivity" value="50"/><float name="conductivity" value="2.5"/>
  <float name="thickness" value="0.1"/></bsdf>
<shape type="ply" id="person"><string name="filename" value="b.ply"/><ref id="tissue" name="bsdf"/></shape>
<shape type="ply" id="person_2"><string name="filename" value="b.ply"/><ref id="tissue_wet" name="bsdf"/></shape>
</scene>"""


@pytest.fixture()
def scene(variant, tmp_path):
    from rfmitsuba import plugins

    assert plugins.register() == plugins.register() == ["human-tissue"]      # idempotent
    import sionna.rt as rt

    trimesh.creation.box(extents=[0.3, 0.4, 1.7]).export(tmp_path / "b.ply")
    (tmp_path / "s.xml").write_text(XML)
    return rt.load_scene(str(tmp_path / "s.xml"), merge_shapes=False)


def test_xml_defaults_and_parameters(scene):
    from rfmitsuba.plugins import human_tissue as ht

    m = scene.get("person").radio_material
    assert isinstance(m, ht.HumanTissueMaterial)
    assert float(m.relative_permittivity[0]) == pytest.approx(40.0)
    assert float(m.conductivity[0]) == pytest.approx(1.7)
    assert float(m.thickness[0]) == pytest.approx(0.2)
    w = scene.get("person_2").radio_material
    assert (float(w.relative_permittivity[0]), float(w.conductivity[0]), float(w.thickness[0])) == \
        pytest.approx((50.0, 2.5, 0.1))
    # the docstring is the reference: it names every parameter and its default
    for p in ("relative_permittivity", "conductivity", "thickness", "scattering_coefficient", "xpd_coefficient"):
        assert p in ht.__doc__
    assert "Default: 40.0" in ht.__doc__ and "Default: 1.7" in ht.__doc__ and "Default: 0.2" in ht.__doc__


def test_complex_permittivity_at_2_4_ghz(scene):
    import mitsuba as mi
    from sionna.rt.utils import complex_relative_permittivity

    scene.frequency = 2.4e9
    m = scene.get("person").radio_material
    omega = 2 * pi * 2.4e9
    eta = complex_relative_permittivity(m.relative_permittivity, m.conductivity, mi.Float(omega))
    # closed form: eta = eps_r - j sigma / (omega eps0) = 40 - 12.73j
    assert float(eta.real[0]) == pytest.approx(40.0)
    assert float(eta.imag[0]) == pytest.approx(-1.7 / (omega * epsilon_0), rel=1e-5)
    assert float(eta.imag[0]) == pytest.approx(-12.73, abs=0.01)


def test_thick_slab_reflects_like_a_half_space(scene):
    """Normal incidence on a thick lossy slab: Sionna's slab coefficient -> Fresnel (1 - n)/(1 + n)."""
    import mitsuba as mi
    from sionna.rt.utils import complex_relative_permittivity, itu_coefficients_single_layer_slab

    m = scene.get("person").radio_material
    f = 2.4e9
    eta = complex_relative_permittivity(m.relative_permittivity, m.conductivity, mi.Float(2 * pi * f))
    r_te, r_tm, t_te, t_tm = itu_coefficients_single_layer_slab(mi.Float(1.0), eta, mi.Float(0.5),
                                                               mi.Float(299792458.0 / f))
    n = np.sqrt(40.0 - 1j * 1.7 / (2 * pi * f * epsilon_0))
    r = (1 - n) / (1 + n)
    got = complex(float(r_te.real[0]), float(r_te.imag[0]))
    assert abs(got - r) < 1e-4
    # |(1 - n)/(1 + n)|^2 at eta = 40 - 12.73j is 0.541 (python: abs((1-n)/(1+n))**2): about half the power
    assert abs(got) ** 2 == pytest.approx(0.541, abs=0.002)
    assert abs(complex(float(t_te.real[0]), float(t_te.imag[0]))) < 1e-6   # nothing crosses 0.5 m of tissue


def test_invalid_parameter_is_rejected(variant):
    from rfmitsuba import plugins

    plugins.register()
    from rfmitsuba.plugins.human_tissue import HumanTissueMaterial

    with pytest.raises(ValueError, match="conductivity"):
        HumanTissueMaterial(name="bad", conductivity=-1.0)
