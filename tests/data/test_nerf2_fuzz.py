"""Fuzzing the NeRF2 folder readers (rfmitsuba.data.nerf2) with hypothesis: whatever the text files
hold, reading either succeeds with finite, well-shaped arrays or raises DatasetError naming the file."""
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rfmitsuba.core.errors import DatasetError
from rfmitsuba.data import nerf2

A = 4
FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])

number = st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=32), st.integers(-10**6, 10**6))
token = st.one_of(number.map(str), st.text(alphabet="0123456789.-+eE ,x\t\r\"#:[]{}'abc", max_size=8))
line = st.lists(token, min_size=0, max_size=5).map(lambda t: ",".join(t))
text_file = st.one_of(
    st.lists(line, max_size=8).map(lambda ls: "\n".join(ls)),
    st.lists(line, max_size=8).map(lambda ls: "\r\n".join(ls)),
    st.binary(max_size=64).map(lambda b: b.decode("latin-1")),
)
yaml_value = st.recursive(
    st.one_of(st.none(), st.booleans(), number, st.text(max_size=6)),
    lambda inner: st.one_of(st.lists(inner, max_size=5), st.dictionaries(st.text(max_size=6), inner, max_size=3)),
    max_leaves=10)
gateway_doc = st.one_of(
    st.fixed_dictionaries({"gateway1": st.fixed_dictionaries(
        {"position": st.lists(number, min_size=0, max_size=4), "orientation": st.lists(number, min_size=0, max_size=5)})},
        optional={"dataset_name": st.text(max_size=5)}),
    st.dictionaries(st.text(max_size=8), yaml_value, max_size=3),
)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    from PIL import Image

    out = tmp_path_factory.mktemp("nerf2") / "f"
    (out / "spectrum").mkdir(parents=True)
    rng = np.random.default_rng(0)
    for i in range(A):
        Image.fromarray(rng.integers(0, 256, (90, 360), dtype=np.uint8), mode="L").save(out / "spectrum" / f"{i + 1:05d}.png")
    good = {"tx_pos.csv": "x,y,z\n" + "1,2,3\n" * A, "train_index.txt": "1\n2\n3\n", "test_index.txt": "4\n"}
    return out, good


def _reset(out, good):
    for name, text in good.items():
        (out / name).write_text(text)
    nerf2._write_gateway(out / "gateway_info.yml", [0, 0, 1], [0, 0, 0, 1])


def _check(out):
    try:
        ds = nerf2.read(out)
    except DatasetError as e:
        assert str(out) in str(e)
        return
    assert ds.antenna_pos.shape == (A, 3) and np.isfinite(ds.antenna_pos).all()
    assert np.isfinite(ds.fixed_pos).all() and np.allclose(ds.rx_to_world @ ds.rx_to_world.T, np.eye(3), atol=1e-6)
    assert len(np.intersect1d(ds.split.antenna_train, ds.split.antenna_test)) == 0


@FUZZ
@given(text=text_file, name=st.sampled_from(["tx_pos.csv", "train_index.txt", "test_index.txt", "gateway_info.yml"]))
def test_any_text_file_reads_or_raises_dataset_error(folder, text, name):
    out, good = folder
    _reset(out, good)
    (out / name).write_bytes(text.encode("utf-8", "surrogatepass"))
    _check(out)


@FUZZ
@given(doc=gateway_doc, crlf=st.booleans())
def test_any_gateway_yaml_reads_or_raises_dataset_error(folder, doc, crlf):
    import yaml

    out, good = folder
    _reset(out, good)
    text = yaml.safe_dump(doc)
    (out / "gateway_info.yml").write_bytes((text.replace("\n", "\r\n") if crlf else text).encode())
    _check(out)
