"""The tracking GP as a portable model: the numpy reference evaluator reproduces gprace (issue 39)."""

from __future__ import annotations

import json

import numpy as np
import pytest


@pytest.mark.parametrize("shared", [True, False])
def test_portable_gp_reproduces_gprace(tmp_path, shared):
    """A GP fitted on a known function, exported, evaluated by the reference evaluator alone:
    mean and both variances equal gprace's to 1e-9 relative, inputs and units named in order."""
    from gprace.gp import make_gp
    from gprace.gp.export import PortableGP, export_gp
    from gprace.timetrial.learning import GPPredictor

    rng = np.random.default_rng(3)
    Z = rng.normal(size=(300, 5)) * [10.0, 0.5, 0.3, 0.05, 3.0] + [30.0, 0, 0, 0, 0]
    Y = np.column_stack([np.sin(Z[:, 1] * 3) + 0.1 * Z[:, 4], np.cos(Z[:, 2] * 2) * Z[:, 3] * 10])
    Y += 0.01 * rng.normal(size=Y.shape)
    ls = np.array([[2.0, 0.8, 1.5, 3.0, 1.0]] * 2) * ([[1.0], [1.0]] if shared else [[1.0], [0.7]])
    gp = make_gp("exact", kernel="se", optimize=False, length_scale=ls, signal_variance=[1.0, 1.0 if shared else 0.6],
                 noise=[1e-2, 1e-2 if shared else 3e-2], shared_kernel=shared).fit(Z, Y)
    assert len(gp._groups()) == (1 if shared else 2)
    pred = GPPredictor(gp, "tracking", inputs=("v_x", "v_y", "yaw_rate", "delta", "a_x"), var_scale=[1.7, 1.2])
    card = export_gp(pred, tmp_path / "gp.h5", tmp_path / "gp.json", dt=0.05, step="rk4")
    assert [i["name"] for i in card["inputs"]] == ["v_x", "v_y", "yaw_rate", "delta", "a_x"]
    assert [i["unit"] for i in card["outputs"]] == ["m/s", "rad/s"]
    assert json.loads((tmp_path / "gp.json").read_text())["dictionary_size"] == 300
    Q = rng.normal(size=(50, 5)) * [12.0, 0.6, 0.4, 0.06, 4.0] + [30.0, 0, 0, 0, 0]
    ref = PortableGP.load(tmp_path / "gp.h5")
    mean, latent, measured = ref.predict(Q)
    m, v = pred(Q)
    _, vm = pred.predictive(Q)
    np.testing.assert_allclose(mean, m, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(latent, v, rtol=1e-7, atol=1e-14)
    np.testing.assert_allclose(measured, vm, rtol=1e-7, atol=1e-14)
    # far from the data the latent variance returns to the calibrated prior
    far = ref.predict(np.full((1, 5), 1e3))[1]
    np.testing.assert_allclose(far[0], np.exp(gp.hyper_.log_sf2) * gp.hyper_.y_scale**2 * [1.7, 1.2], rtol=1e-9)
