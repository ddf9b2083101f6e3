"""Tests of rfmitsuba.core.direct_io: ``.npy`` files written past the page cache."""
from __future__ import annotations

import errno
import hashlib
import os

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rfmitsuba.core import direct_io
from rfmitsuba.core.direct_io import save_npy


def _same_as_np_save(path, array, *, direct: bool) -> None:
    digest = save_npy(path, array, direct=direct)
    ref = path.with_name("ref.npy")
    np.save(ref, array, allow_pickle=False)
    assert path.read_bytes() == ref.read_bytes()
    assert digest == hashlib.sha256(ref.read_bytes()).hexdigest()
    np.testing.assert_array_equal(np.load(path), array)


@pytest.mark.parametrize("direct", [True, False])
@pytest.mark.parametrize("shape,dtype", [((0,), np.float32), ((3, 5), np.complex64), ((900, 9, 36), np.float32),
                                         ((1000, 1001), np.float64), ((2, 3), np.int16), ((), np.float32)])
def test_bytes_and_digest_are_np_saves(tmp_path, shape, dtype, direct):
    a = (np.random.default_rng(1).random(shape) * 100).astype(dtype)
    _same_as_np_save(tmp_path / "a.npy", a, direct=direct)


@settings(max_examples=40, deadline=None)
@given(n=st.integers(0, 40_000), stage_blocks=st.integers(1, 4), fortran=st.booleans())
def test_any_length_across_staging_pieces(tmp_path_factory, n, stage_blocks, fortran):
    """Files of every length against a staging buffer of 1-4 blocks: full pieces, a last piece
    that ends inside a block or on its edge; Fortran-ordered and strided arrays too."""
    mp = pytest.MonkeyPatch()
    try:
        mp.setattr(direct_io, "STAGE_BYTES", stage_blocks * direct_io.BLOCK)
        mp.setattr(direct_io, "_LOCAL", type(direct_io._LOCAL)())    # a staging buffer of that size
        a = np.arange(n, dtype=np.uint8)
        a = np.asfortranarray(a.reshape(-1, 2)) if fortran and n % 2 == 0 else a[::-1] if fortran else a
        _same_as_np_save(tmp_path_factory.mktemp("f") / "a.npy", a, direct=True)
    finally:
        mp.undo()


def test_a_file_system_without_o_direct_gets_a_buffered_write(tmp_path, monkeypatch):
    """``O_DIRECT`` refused (EINVAL, as tmpfs does): the same bytes through a buffered write."""
    real_open = os.open
    calls = []

    def refusing_open(path, flags, *args, **kw):
        calls.append(bool(flags & getattr(os, "O_DIRECT", 0)))
        if flags & getattr(os, "O_DIRECT", 0):
            raise OSError(errno.EINVAL, "Invalid argument")
        return real_open(path, flags, *args, **kw)

    monkeypatch.setattr(os, "open", refusing_open)
    _same_as_np_save(tmp_path / "a.npy", np.arange(10_000, dtype=np.float32), direct=True)
    if hasattr(os, "O_DIRECT"):
        assert calls[0] is True          # it was tried first


def test_other_errors_are_not_hidden(tmp_path):
    with pytest.raises(FileNotFoundError):
        save_npy(tmp_path / "missing" / "a.npy", np.zeros(3))


def test_object_arrays_are_refused(tmp_path):
    with pytest.raises(ValueError, match="a.npy: object arrays are not written"):
        save_npy(tmp_path / "a.npy", np.array([{"x": 1}], dtype=object))


@pytest.mark.parametrize("direct", [True, False])
def test_blocks_give_the_file_of_their_concatenation(tmp_path, direct, monkeypatch):
    """Blocks of uneven sizes, some empty and one of another dtype (cast), across staging
    pieces: the bytes and digest of ``np.save`` of the whole array."""
    monkeypatch.setattr(direct_io, "STAGE_BYTES", 2 * direct_io.BLOCK)
    monkeypatch.setattr(direct_io, "_LOCAL", type(direct_io._LOCAL)())
    whole = np.random.default_rng(2).random((23, 7, 5)).astype(np.float32)
    cuts = [0, 0, 4, 5, 16, 23]
    blocks = [whole[a:b] for a, b in zip(cuts, cuts[1:])]
    blocks[3] = blocks[3].astype(np.float64)
    digest = direct_io.save_npy_blocks(tmp_path / "a.npy", iter(blocks), shape=whole.shape, direct=direct)
    np.save(tmp_path / "ref.npy", whole)
    assert (tmp_path / "a.npy").read_bytes() == (tmp_path / "ref.npy").read_bytes()
    assert digest == hashlib.sha256((tmp_path / "ref.npy").read_bytes()).hexdigest()


@pytest.mark.parametrize("blocks,match", [
    ([np.zeros((3, 4))], "blocks hold 3 rows, expected 5"),
    ([np.zeros((3, 4)), np.zeros((3, 4))], "blocks hold more than 5 rows"),
    ([np.zeros((5, 3))], r"a block of shape \(5, 3\), expected \[k, 4\]"),
])
def test_blocks_that_do_not_make_the_shape_are_an_error(tmp_path, blocks, match):
    with pytest.raises(ValueError, match=match):
        direct_io.save_npy_blocks(tmp_path / "a.npy", blocks, shape=(5, 4))


def test_blocks_on_a_file_system_without_o_direct(tmp_path, monkeypatch):
    """Refused at the open: nothing was consumed, so the buffered write gets every block."""
    real_open = os.open

    def refusing_open(path, flags, *args, **kw):
        if flags & getattr(os, "O_DIRECT", 0):
            raise OSError(errno.EINVAL, "Invalid argument")
        return real_open(path, flags, *args, **kw)

    monkeypatch.setattr(os, "open", refusing_open)
    whole = np.arange(60, dtype=np.float32).reshape(6, 10)
    direct_io.save_npy_blocks(tmp_path / "a.npy", (whole[k:k + 4] for k in (0, 4)), shape=whole.shape)
    np.testing.assert_array_equal(np.load(tmp_path / "a.npy"), whole)
