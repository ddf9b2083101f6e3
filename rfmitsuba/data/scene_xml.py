"""Reading a Mitsuba scene XML: its shapes, meshes and transforms (no Mitsuba or Sionna needed).
"""
from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from ..core.errors import SceneError

STRUCTURE_PREFIXES = ("wall", "floor", "ceiling", "door", "window")


PART_SEP = "__"


def object_name(shape_id: str) -> str:
    """Sionna's object name for a shape id (a leading ``mesh-`` removed)."""
    return shape_id[5:] if shape_id.startswith("mesh-") else shape_id


def object_of(shape_id: str) -> str:
    """The object a shape belongs to: its name up to ``__`` (``bed__soft_textile`` -> ``bed``)."""
    return object_name(shape_id).split(PART_SEP, 1)[0]


def kind_of(shape_id: str) -> str:
    """``"wall"``, ``"floor"``, ``"ceiling"``, ``"door"``, ``"window"`` or ``"furniture"``."""
    name = object_name(shape_id)
    for p in STRUCTURE_PREFIXES:
        if name.startswith(p):
            return p
    return "furniture"


@dataclass
class Shape:
    """One shape of the scene: id, kind, material id and its mesh in world coordinates (metres)."""

    id: str
    kind: str
    material: str
    mesh: trimesh.Trimesh

    @property
    def object(self) -> str:
        return object_of(self.id)


def _numbers(text: str, n: int, where: str) -> list[float]:
    try:
        vals = [float(v) for v in re.split(r"[,\s]+", text.strip()) if v]
    except ValueError:
        raise SceneError(f"{where}: expected {n} numbers, got {text!r}") from None
    if len(vals) != n:
        raise SceneError(f"{where}: expected {n} numbers, got {text!r}")
    return vals


def _xyz(el: ET.Element, default: float, where: str) -> np.ndarray:
    if "value" in el.attrib:
        vals = re.split(r"[,\s]+", el.attrib["value"].strip())
        if len(vals) == 1:
            return np.full(3, float(_numbers(vals[0], 1, where)[0]))
        return np.array(_numbers(el.attrib["value"], 3, where))
    try:
        return np.array([float(el.attrib.get(k, default)) for k in "xyz"])
    except ValueError:
        raise SceneError(f"{where}: bad number in {el.attrib}") from None


def _rotation(axis: np.ndarray, angle_deg: float) -> np.ndarray:
    """Mitsuba's ``rotate``: Rodrigues' formula with the axis as given (Mitsuba does not normalise
    it, so a non-unit axis also scales; we follow the loader, since that is what Sionna traces)."""
    if not np.any(axis):
        raise SceneError("rotate: zero axis")
    th = math.radians(angle_deg)
    c, s = math.cos(th), math.sin(th)
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    m = np.eye(4)
    m[:3, :3] = c * np.eye(3) + s * k + (1.0 - c) * np.outer(axis, axis)
    return m


def _to_world(el: ET.Element, where: str) -> np.ndarray:
    m = np.eye(4)
    for op in el:
        tag = op.tag
        if tag == "matrix":
            vals = _numbers(op.attrib.get("value", ""), 16, f"{where} matrix")
            t = np.array(vals).reshape(4, 4)
        elif tag == "translate":
            t = np.eye(4)
            t[:3, 3] = _xyz(op, 0.0, f"{where} translate")
        elif tag == "scale":
            t = np.diag([*_xyz(op, 1.0, f"{where} scale"), 1.0])
        elif tag == "rotate":
            axis = _xyz(op, 0.0, f"{where} rotate")
            try:
                angle = float(op.attrib.get("angle", "0"))
            except ValueError:
                raise SceneError(f"{where} rotate: bad angle {op.attrib.get('angle')!r}") from None
            t = _rotation(axis, angle)
        else:
            raise SceneError(f"{where}: transform entry <{tag}> is not supported "
                             f"(matrix, translate, scale, rotate are)")
        m = t @ m
    return m


def _substitute(root: ET.Element, xml_path: Path) -> None:
    defaults = {d.attrib.get("name"): d.attrib.get("value", "") for d in root.iter("default")}
    if not defaults:
        return
    for el in root.iter():
        for k, v in el.attrib.items():
            if "$" in v:
                def rep(mt):
                    name = mt.group(1)
                    if name not in defaults:
                        raise SceneError(f"{xml_path}: ${name} has no <default>")
                    return defaults[name]
                el.attrib[k] = re.sub(r"\$([A-Za-z_][A-Za-z0-9_]*)", rep, v)


def read_shapes(xml_path: str | Path) -> list[Shape]:
    """Every mesh shape of a Mitsuba scene XML, in world coordinates."""
    xml_path = Path(xml_path)
    if not xml_path.is_file():
        raise SceneError(f"scene file {xml_path} does not exist")
    try:
        root = ET.parse(xml_path).getroot()
    except ET.ParseError as e:
        raise SceneError(f"{xml_path}: malformed XML: {e}") from None
    if root.tag != "scene":
        raise SceneError(f"{xml_path}: root element is <{root.tag}>, expected <scene>")
    _substitute(root, xml_path)
    if root.find("include") is not None:
        raise SceneError(f"{xml_path}: <include> is not supported; put every shape in one file")
    shapes = []
    for i, s in enumerate(root.findall("shape")):
        sid = s.attrib.get("id") or s.attrib.get("name") or f"shape_{i}"
        stype = s.attrib.get("type", "")
        where = f"{xml_path}: shape {sid!r}"
        if stype not in ("ply", "obj"):
            raise SceneError(f"{where}: shape type {stype!r} is not supported (only 'ply' and 'obj' meshes)")
        fn = s.find("string[@name='filename']")
        if fn is None or not fn.attrib.get("value"):
            raise SceneError(f"{where}: no <string name=\"filename\">")
        mesh_path = (xml_path.parent / fn.attrib["value"]).resolve()
        if not mesh_path.is_file():
            raise SceneError(f"{where}: mesh file {mesh_path} does not exist")
        try:
            mesh = trimesh.load(mesh_path, file_type=stype, force="mesh", process=True)
        except Exception as e:  # noqa: BLE001 - trimesh raises many types for bad files
            raise SceneError(f"{where}: cannot read mesh {mesh_path}: {e}") from None
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
            raise SceneError(f"{where}: mesh {mesh_path} has no triangles")
        tw = s.find("transform[@name='to_world']")
        if tw is not None:
            mesh.apply_transform(_to_world(tw, where))
        if not np.all(np.isfinite(mesh.vertices)):
            raise SceneError(f"{where}: mesh {mesh_path} has non-finite vertices")
        ref = s.find("ref[@name='bsdf']")
        if ref is None:
            ref = s.find("ref")
        inner = s.find("bsdf")
        material = ref.attrib.get("id", "") if ref is not None else (inner.attrib.get("id", "") if inner is not None else "")
        shapes.append(Shape(sid, kind_of(sid), material, mesh))
    if not shapes:
        raise SceneError(f"{xml_path}: no shapes")
    return shapes
