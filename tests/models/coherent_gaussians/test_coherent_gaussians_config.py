"""rfmitsuba.models.coherent_gaussians.config: the coherent Gaussian field's options
(:class:`CoherentGaussianConfig`).

Options and values that were removed: a saved state that used one loads where the option held the
value the code now behaves as and is refused, naming the option, where it did not; a user's
configuration that names one is told it was removed."""
from __future__ import annotations

import numpy as np
import pytest
from coherent_gaussians_cases import _field


#: every test on one Dr.Jit thread (the ``one_thread`` fixture of tests/conftest.py)
pytestmark = pytest.mark.usefixtures("one_thread")


def test_saved_states_with_removed_options_load_where_exact():
    """A field saved with an option that was removed loads where the option held the value the
    code now behaves as (``material_through = false``, any ``amp_l1`` = 0, ``frame_search =
    "apply"``: it only steered the start), and is refused, naming the option, where it did not
    (``material_through = true``: its parameters cannot be drawn); a user's configuration that
    names a removed option is told it was removed."""
    import json

    from rfmitsuba.core import config as C
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.models.coherent_gaussians import CoherentGaussianConfig, CoherentGaussianField

    f = _field()
    st = f.state_dict()
    meta = json.loads(str(st["meta"]))
    meta["config"].update(material_through=False, amp_l1=0.0, init_transmission=0.5, frame_search="apply",
                          frame_min_gain=0.01, calibration_twin="other", coupling_model="neighbours")
    st["meta"] = np.asarray(json.dumps(meta))
    back = CoherentGaussianField.from_state_dict(st)
    assert back.cfg.frame_search == "report"
    np.testing.assert_array_equal(back.params["img_amp"].numpy(), f.params["img_amp"].numpy())
    meta["config"]["material_through"] = True
    st["meta"] = np.asarray(json.dumps(meta))
    with pytest.raises(ConfigError, match="material_through = True: this saved file used an option that was removed"):
        CoherentGaussianField.from_state_dict(st)
    with pytest.raises(ConfigError, match="amp_l1: this option was removed"):
        C.from_dict(CoherentGaussianConfig, {"amp_l1": 0.0})
    with pytest.raises(ConfigError, match="frame_search = 'apply': this value was removed"):
        C.from_dict(CoherentGaussianConfig, {"frame_search": "apply"})
