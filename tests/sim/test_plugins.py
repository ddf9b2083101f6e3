"""rfmitsuba.plugins: registration, and documentation that stays true.

Every plugin module of :mod:`rfmitsuba.plugins` (a module with ``PLUGIN_NAME``)
must document itself like a Mitsuba plugin: a parameter table
(``.. list-table::`` rows ``* - name``) naming every XML parameter the plugin
registers, with its unit or range, and an XML example that loads. The
registered XML parameters are the keyword arguments of the plugin class
(``name`` and ``props`` aside): the plugin maps XML properties onto them.
"""
from __future__ import annotations

import importlib
import inspect
import pkgutil
import re
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import rfmitsuba.plugins as plugins_pkg
import trimesh
from scipy.constants import epsilon_0, pi


def _plugin_modules():
    out = []
    for info in pkgutil.iter_modules(plugins_pkg.__path__):
        mod = importlib.import_module(f"rfmitsuba.plugins.{info.name}")
        if hasattr(mod, "PLUGIN_NAME"):
            out.append(mod)
    return out


def _plugin_class(mod):
    """The class that ``register`` hands to Mitsuba: the one defined in the module whose name ends in
    ``Material`` or that subclasses a Sionna radio material."""
    from sionna.rt import RadioMaterialBase

    classes = [c for _, c in inspect.getmembers(mod, inspect.isclass)
               if c.__module__ == mod.__name__ and issubclass(c, RadioMaterialBase)]
    assert len(classes) == 1, f"{mod.__name__}: expected one plugin class, found {classes}"
    return classes[0]


def _xml_parameters(cls) -> set[str]:
    sig = inspect.signature(cls.__init__)
    return {n for n, p in sig.parameters.items()
            if n not in ("self", "name", "props") and p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD)}


def _documented(doc: str) -> dict[str, tuple[str, str]]:
    """Rows of the first list-table: name -> (type, description)."""
    table = doc.split(".. list-table::", 1)
    assert len(table) == 2, "no '.. list-table::' parameter table in the docstring"
    body = []
    for line in table[1].splitlines()[1:]:
        if line.strip() and not line[0].isspace():  # the table ends where the indentation does
            break
        body.append(line)
    rows = re.split(r"^\s*\* - ", "\n".join(body), flags=re.M)[1:]
    out = {}
    for row in rows:
        cells = [c.strip() for c in re.split(r"^\s*- ", row, flags=re.M)]
        if len(cells) < 3:
            break
        name, typ, desc = cells[0].strip(), cells[1].strip(), " ".join(cells[2].split())
        out[name] = (typ, desc)
    out.pop("Parameter", None)
    return out


def _xml_examples(doc: str) -> list[str]:
    blocks = re.findall(r"\.\. code-block:: xml\n\n((?:[ \t]+.*\n|\n)+)", doc + "\n")
    return [inspect.cleandoc(b) for b in blocks]


MODULES = _plugin_modules()


def test_there_are_plugins():
    assert [m.PLUGIN_NAME for m in MODULES] == ["body-tissue"]


def test_register_is_idempotent(variant):
    first = plugins_pkg.register()
    assert plugins_pkg.register() == first
    assert set(first) == {m.PLUGIN_NAME for m in MODULES}


@pytest.mark.parametrize("mod", MODULES, ids=lambda m: m.PLUGIN_NAME)
def test_docstring_names_every_xml_parameter(mod, variant):
    documented = _documented(mod.__doc__)
    registered = _xml_parameters(_plugin_class(mod))
    assert registered, "plugin class takes no parameters?"
    missing = registered - set(documented)
    assert not missing, f"{mod.__name__}: XML parameters not in the docstring table: {sorted(missing)}"
    extra = set(documented) - registered
    assert not extra, f"{mod.__name__}: docstring documents parameters the plugin does not take: {sorted(extra)}"
    for name, (typ, desc) in documented.items():
        assert typ in ("float", "rgb", "string", "integer", "boolean"), f"{name}: unknown XML type {typ!r}"
        assert "Default" in desc, f"{name}: no default given"
        if typ == "float":  # a unit, or a statement that there is none / a range
            assert re.search(r"\b(metres|S/m|unitless|\\in \[0, 1\]|in \[0, 1\])", desc), f"{name}: no unit"


@pytest.mark.parametrize("mod", MODULES, ids=lambda m: m.PLUGIN_NAME)
def test_every_documented_parameter_loads_from_xml(mod, variant):
    """Each table row, given in XML with a non-default value, reaches the material."""
    import mitsuba as mi
    import numpy as np

    plugins_pkg.register()
    values = {"float": ("0.37", 0.37), "rgb": ("0.1, 0.2, 0.3", (0.1, 0.2, 0.3))}
    for name, (typ, _) in _documented(mod.__doc__).items():
        text, want = values[typ]
        tag = "float" if typ == "float" else "rgb"
        # permittivity must be >= 1
        if name == "relative_permittivity":
            text, want = "3.7", 3.7
        mat = mi.load_string(f'<bsdf version="3.0.0" type="{mod.PLUGIN_NAME}" id="m">'
                             f'<{tag} name="{name}" value="{text}"/></bsdf>')
        got = getattr(mat, name)
        got = np.asarray(got, dtype=float).ravel()
        np.testing.assert_allclose(got, np.ravel(want), rtol=1e-6, err_msg=f"{mod.PLUGIN_NAME}.{name}")


@pytest.mark.parametrize("mod", MODULES, ids=lambda m: m.PLUGIN_NAME)
def test_unknown_xml_parameter_is_rejected(mod, variant):
    """The table is the whole interface: a name it does not list fails to load."""
    import mitsuba as mi

    plugins_pkg.register()
    with pytest.raises(RuntimeError):
        mi.load_string(f'<bsdf version="3.0.0" type="{mod.PLUGIN_NAME}" id="m">'
                       f'<float name="not_a_parameter" value="1"/></bsdf>')


@pytest.mark.parametrize("mod", MODULES, ids=lambda m: m.PLUGIN_NAME)
def test_docstring_xml_example_loads(mod, variant, tmp_path):
    """The XML example in the docstring is a valid scene fragment using only documented parameters."""
    import mitsuba as mi

    from rfmitsuba.sim import person as person

    plugins_pkg.register()
    examples = _xml_examples(mod.__doc__)
    assert examples, f"{mod.__name__}: no '.. code-block:: xml' example"
    documented = set(_documented(mod.__doc__))
    for ex in examples:
        root = ET.fromstring(f"<scene version='3.0.0'>{ex}</scene>")
        bsdfs = [b for b in root.iter("bsdf") if b.get("type") == mod.PLUGIN_NAME]
        assert bsdfs, "the example does not use the plugin"
        for b in bsdfs:
            names = {c.get("name") for c in b}
            assert names <= documented, f"example uses undocumented parameters {names - documented}"
        # point mesh filenames at a real mesh, then load the whole example as a scene
        for s in root.iter("string"):
            if s.get("name") == "filename":
                p = tmp_path / s.get("value")
                person.write_person_ply(p)
        scene = mi.load_string(ET.tostring(root, encoding="unicode").replace("filename\" value=\"",
                                                                               f"filename\" value=\"{tmp_path}/"))
        assert len(scene.shapes()) >= 1


# ---------------------------------------------------------------- physics of body-tissue
XML = """<scene version="2.1.0">
<bsdf type="body-tissue" id="tissue"/>
<bsdf type="body-tissue" id="tissue_wet">
  <float name="relative_permittivity" value="50"/><float name="conductivity" value="2.5"/>
  <float name="thickness" value="0.1"/></bsdf>
<shape type="ply" id="person"><string name="filename" value="b.ply"/><ref id="tissue" name="bsdf"/></shape>
<shape type="ply" id="person_2"><string name="filename" value="b.ply"/><ref id="tissue_wet" name="bsdf"/></shape>
</scene>"""


@pytest.fixture()
def scene(variant, tmp_path):
    from rfmitsuba import plugins

    assert plugins.register() == plugins.register() == ["body-tissue"]      # idempotent
    import sionna.rt as rt

    trimesh.creation.box(extents=[0.3, 0.4, 1.7]).export(tmp_path / "b.ply")
    (tmp_path / "s.xml").write_text(XML)
    return rt.load_scene(str(tmp_path / "s.xml"), merge_shapes=False)


def test_xml_defaults_and_parameters(scene):
    from rfmitsuba.plugins import body_tissue as ht

    m = scene.get("person").radio_material
    assert isinstance(m, ht.BodyTissueMaterial)
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
    from sionna.rt.utils import (
        complex_relative_permittivity,
        itu_coefficients_single_layer_slab,
    )

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
    from rfmitsuba.plugins.body_tissue import BodyTissueMaterial

    with pytest.raises(ValueError, match="conductivity"):
        BodyTissueMaterial(name="bad", conductivity=-1.0)
