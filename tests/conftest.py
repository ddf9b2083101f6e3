"""Shared fixtures: the Dr.Jit/Mitsuba variant, small session-wide data, and the two-stage models of the
localisation tests.

The ``variant`` fixture follows Mitsuba's test suite: tests that need the JIT
take it and run on the LLVM backend (or on CUDA with ``RFMITSUBA_VARIANT=cuda``).
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

import rfmitsuba  # noqa: F401  (points Dr.Jit at libLLVM before anything imports drjit)

os.environ.setdefault("RFMITSUBA_QUIET", "1")


@pytest.fixture(scope="session")
def variant() -> str:
    """The active Mitsuba variant (``llvm_ad_mono_polarized`` on CPU)."""
    from rfmitsuba.core import backend

    return backend.set_variant(os.environ.get("RFMITSUBA_VARIANT") or "llvm")


@pytest.fixture
def one_thread(variant):
    """Dr.Jit on one thread, so gradient scatter-adds sum in a fixed order (finite-difference
    checks); the thread count is restored afterwards."""
    import drjit as dr

    old = dr.thread_count()
    dr.set_thread_count(1)
    yield
    dr.set_thread_count(old)


# ----------------------------------------------------------------------------- tiny hand-made rooms
def _quad_ply(path, corners) -> None:
    """Write one planar quad (two triangles, both windings) as an ASCII PLY file."""
    import numpy as np

    v = np.asarray(corners, float)
    lines = ["ply", "format ascii 1.0", "element vertex 4", "property float x", "property float y",
             "property float z", "element face 2", "property list uchar int vertex_indices", "end_header"]
    lines += [f"{x:.6f} {y:.6f} {z:.6f}" for x, y, z in v]
    lines += ["3 0 1 2", "3 0 2 3"]
    path.write_text("\n".join(lines) + "\n")


def write_quads_scene(folder, quads: dict, *, material: str = "concrete") -> Path:
    """A Sionna scene of named planar quads (id -> 4 corners [4, 3], metres), one ITU material.

    Returns the XML path. Used by the physics tests (free space, one plate, a closed box).
    """
    from pathlib import Path

    folder = Path(folder)
    (folder / "meshes").mkdir(parents=True, exist_ok=True)
    shapes = []
    for name, corners in quads.items():
        _quad_ply(folder / "meshes" / f"{name}.ply", corners)
        shapes.append(f'  <shape type="ply" id="{name}"><string name="filename" value="meshes/{name}.ply"/>'
                      f'<boolean name="face_normals" value="true"/><ref id="mat-itu-{material}" name="bsdf"/></shape>')
    xml = ['<scene version="2.1.0">',
           f'  <bsdf type="itu-radio-material" id="mat-itu-{material}"><string name="type" value="{material}"/>'
           '<float name="thickness" value="0.1"/></bsdf>', *shapes, "</scene>"]
    path = folder / "scene.xml"
    path.write_text("\n".join(xml) + "\n")
    return path


def box_quads(lo=(0.0, 0.0, 0.0), hi=(4.0, 3.0, 2.6)) -> dict:
    """The six faces of an axis-aligned box room."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    return {
        "floor": [(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0)],
        "ceiling": [(x0, y0, z1), (x0, y1, z1), (x1, y1, z1), (x1, y0, z1)],
        "wall-xmin": [(x0, y0, z0), (x0, y1, z0), (x0, y1, z1), (x0, y0, z1)],
        "wall-xmax": [(x1, y0, z0), (x1, y0, z1), (x1, y1, z1), (x1, y1, z0)],
        "wall-ymin": [(x0, y0, z0), (x0, y0, z1), (x1, y0, z1), (x1, y0, z0)],
        "wall-ymax": [(x0, y1, z0), (x1, y1, z0), (x1, y1, z1), (x0, y1, z1)],
    }


@pytest.fixture(scope="session")
def box_room(tmp_path_factory):
    """XML path of a closed 4 x 3 x 2.6 m concrete box room (corner at the origin)."""
    return write_quads_scene(tmp_path_factory.mktemp("box_room"), box_quads())


@pytest.fixture(scope="session")
def quick_dataset(tmp_path_factory, variant):
    """A quick bedroom dataset (moving RX, 36 antenna positions x 5 states), generated once per session.

    Same as ``rfmitsuba generate bedroom --task rx --quick --seed 0``.
    """
    from rfmitsuba.sim import generate as gen

    out = tmp_path_factory.mktemp("quick_bedroom") / "ds"
    return gen.generate(out, gen.quick_config("bedroom", task="rx", seed=0), quiet=True)


@pytest.fixture(scope="session")
def two_people_dataset(tmp_path_factory, variant):
    """A quick bedroom dataset with two people walking at once (moving RX, 36 antenna positions x
    5 states), generated once per session: ``rfmitsuba generate bedroom --quick --people 2``."""
    from rfmitsuba.sim import generate as gen

    out = tmp_path_factory.mktemp("two_people") / "ds"
    return gen.generate(out, gen.quick_config("bedroom", task="rx", seed=0, people=2), quiet=True)


@pytest.fixture(scope="session")
def synthetic_ds(tmp_path_factory, variant):
    """A synthetic dynamic dataset (30 antennas x (1 + 6) states) rendered from known background and
    person Gaussians (rfmitsuba.sim.synthetic.make_dataset, seed 0); no Sionna."""
    from rfmitsuba.sim import synthetic

    out = tmp_path_factory.mktemp("synthetic") / "ds"
    synthetic.make_dataset(out, antennas=30, people=6, seed=0)
    return out


@pytest.fixture(scope="session")
def tiny_reproduction(tmp_path_factory, variant):
    """``reproduce`` at the tiny size, killed after 4 jobs (Stopped) and resumed to the end.

    Returns (out folder, config, report path, {DONE marker: mtime_ns} of the jobs finished
    before the stop)."""
    from rfmitsuba.experiments.reproduce import Stopped, reproduce
    from rfmitsuba.experiments.sizes import size_config

    out = tmp_path_factory.mktemp("tiny_reproduce") / "out"
    cfg = size_config("tiny")
    with pytest.raises(Stopped):
        reproduce(out, cfg, stop_after=4, quiet=True)
    done = {p: p.stat().st_mtime_ns for p in out.glob("jobs/*/*/metrics.json")}
    report = reproduce(out, cfg, quiet=True)
    return out, cfg, report, done


# ------------------------------------------------- device-free localisation (tests/eval/locate)
@pytest.fixture(scope="module")
def known_model(synthetic_ds, variant):
    """A two-stage model of known fields on the synthetic dataset's geometry: a background of the
    direct path, one wall reflection and two scatterers; a person who blocks strongly and carries
    three scatterers."""
    from rfmitsuba.data.samples import SampleData
    from rfmitsuba.eval.locate import TwoStage
    from rfmitsuba.models.coherent_gaussians import CoherentGaussianConfig, CoherentGaussianField
    from rfmitsuba.models.coherent_gaussians_person import CoherentGaussianPersonConfig, CoherentGaussianPersonField

    data = SampleData.open_samples(synthetic_ds, states="all")
    A = np.stack([np.eye(3), np.diag([-1.0, 1.0, 1.0])])
    bg = CoherentGaussianField(A, np.array([0, 1]), np.array([[1.0, 2.5, 2.0], [3.2, 0.4, 0.5]]),
                               cfg=CoherentGaussianConfig(init_extent=1.5), readout="amplitude", wavefront="spherical",
                               vis_center=np.array([2.0, 1.75, 1.0]), frequency_hz=float(data.frequency_hz), seed=0)
    bg.freeze()
    pcfg = CoherentGaussianPersonConfig(num_points=3, person_octaves=1, init_gain=0.5, init_strength=0.9,
                                        init_block_radius=0.3)
    person = CoherentGaussianPersonField.for_background(bg, cfg=pcfg, seed=1)
    person.freeze()
    train = np.isin(data.states, np.asarray(data.split.person_train) + 1) & (data.antennas == 0)
    return TwoStage(background=bg, person=person, data=data, feet_z=0.0, walk=data.person_pos[train], job=synthetic_ds)


@pytest.fixture(scope="module")
def true_feet():
    """The person's feet position [m] the known model's query PAS are rendered at."""
    return np.array([1.9, 1.7, 0.0])


@pytest.fixture(scope="module")
def pas_at():
    """The known model's raw PAS float32 [K, 90, 360] with the feet at ``feet`` (or no person)."""
    return _pas_at


def _pas_at(model, feet, antenna_pos, *, person=True):
    """The model's raw PAS float32 [K, 90, 360] with the person's feet at ``feet`` (or no person)."""
    import drjit as dr

    from rfmitsuba.eval.predict import views_at
    from rfmitsuba.models.base import render

    views = views_at(model.data, antenna_pos)
    ext = model.features(np.tile(feet, (len(antenna_pos), 1)))
    views.inputs = lambda field: ext
    fields = [model.background, model.person] if person else [model.background]
    with dr.suspend_grad():
        img = render(fields, views, height=90, width=360, normalize=False)
    return np.asarray(img.numpy(), np.float32).reshape(-1, 90, 360)


@pytest.fixture(scope="module")
def tiny_two_stage(synthetic_ds, tmp_path_factory, variant):
    """A tiny comparison folder (Baseline + Ours, one seed) on the synthetic dataset."""
    from rfmitsuba.core import config as C
    from rfmitsuba.experiments.compare import CompareConfig, compare

    out = tmp_path_factory.mktemp("locate_cmp") / "cmp"
    cfg = C.override(CompareConfig(), ["methods=['baseline','ours']", "seeds=[0]", "train.stage1_iterations=6",
                                       "train.val_every=6", "train.stage2_iterations=4"])
    compare(synthetic_ds, out, cfg=cfg, progress=False)
    return out
