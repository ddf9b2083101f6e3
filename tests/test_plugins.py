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

import pytest

import rfmitsuba.plugins as plugins_pkg


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
    assert [m.PLUGIN_NAME for m in MODULES] == ["human-tissue"]


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

    from rfmitsuba import human

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
                human.write_human_ply(p)
        scene = mi.load_string(ET.tostring(root, encoding="unicode").replace("filename\" value=\"",
                                                                               f"filename\" value=\"{tmp_path}/"))
        assert len(scene.shapes()) >= 1
