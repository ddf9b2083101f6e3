"""Host arrays behind Dr.Jit columns: uploads that remember the array they came from
(:func:`upload_kept`), and columns read back as [M, D] host arrays without a kernel where they
are such uploads (:func:`host_columns`). The host MLP ops hand activations and gradients to
one another through them."""
from __future__ import annotations

from collections import OrderedDict

import numpy as np

from ...core.upload import upload_rows


#: the host arrays behind :class:`HostMLP`'s latest uploads (its outputs and input gradients):
#: the columns' JIT indices -> (host array [M, D], the columns, which hold those indices). The
#: next op reads a hit from here instead of evaluating the columns, copying them back and
#: stacking them: the EM network's trunk -> head in the forward pass, head -> trunk in the
#: backward pass (10 000 Gaussians x 64 features). The columns are kept alive with their array,
#: so their indices cannot be reused for other arrays while an entry exists.
_UPLOADED: OrderedDict = OrderedDict()
_UPLOADED_MAX = 8


def upload_kept(array_type, values: np.ndarray) -> list:
    """:func:`rfmitsuba.core.upload.upload_rows` (Dr.Jit borrows ``values``, which nobody
    writes afterwards), remembering ``values`` for :func:`host_columns`."""
    cols = upload_rows(array_type, values)
    key = tuple(c.index for c in cols)
    _UPLOADED[key] = (values, cols)
    _UPLOADED.move_to_end(key)
    while len(_UPLOADED) > _UPLOADED_MAX:
        _UPLOADED.popitem(last=False)
    return cols


def _kept(values: list) -> np.ndarray | None:
    """The host array that D ``Float`` [M] were uploaded from, when they are the columns of a
    recent :func:`upload_kept` (read only), else None."""
    hit = _UPLOADED.get(tuple(v.index for v in values))
    return None if hit is None else hit[0]


def host_columns(groups: list) -> list:
    """Lists of D ``Float`` [M] -> float32 [M, D] host arrays (read only), one per list: the
    array a list was uploaded from when it is the columns of a recent :func:`upload_kept`
    (nothing runs), otherwise the list evaluated (one kernel for all such lists; the call waits
    for it) and stacked (an F-ordered array). An empty list gives None."""
    import drjit as dr

    found = [_kept(g) if g else None for g in groups]
    missing = [g for g, f in zip(groups, found) if g and f is None]
    if missing:
        dr.eval(missing)
    # a miss is stacked column by column into a [D, M] array and read through its transpose (an
    # F-ordered [M, D] view, which the host's matrix products take as it is): 39 columns of 10 000
    # took 0.09 ms against 0.37 ms when written row by row
    return [None if not g else f if f is not None else np.stack([np.asarray(v.numpy(), np.float32) for v in g]).T
            for g, f in zip(groups, found)]
