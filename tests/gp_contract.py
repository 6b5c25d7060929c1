"""Shared contract tests for GP backends.

Every backend, built-in or third-party, gets the same tests by subclassing
:class:`GPBackendContract` in a test module and setting ``backend_name`` (and, if needed,
``settings`` for small, fast fits)::

    from gp_contract import GPBackendContract

    class TestMyGP(GPBackendContract):
        backend_name = "my-gp"
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from gprace.errors import ArtifactError, InputError
from gprace.gp import load_model, make_gp, save_model, train_inputs
from gprace.gp.base import TRAIN_INPUTS
from gprace.io.artifacts import Artifact, write_artifact


def smooth_data(n: int = 60, seed: int = 0, noise: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """Two smooth outputs of three inputs (the third input is irrelevant to output 0)."""
    rng = np.random.default_rng(seed)
    Z = rng.uniform(-2.0, 2.0, (n, 3))
    Y = np.column_stack([np.sin(1.5 * Z[:, 0]) + 0.3 * Z[:, 1], 0.5 * Z[:, 1] * Z[:, 2] - 0.2 * Z[:, 0]])
    return Z, Y + noise * rng.standard_normal(Y.shape)


class GPBackendContract:
    backend_name: str = ""
    settings: dict[str, Any] = {}

    def make(self, **kw: Any):
        return make_gp(self.backend_name, **{**self.settings, **kw})

    # -- estimator contract -----------------------------------------------------------------------
    def test_fit_returns_self_shapes_and_positive_variance(self):
        Z, Y = smooth_data()
        gp = self.make()
        assert gp.fit(Z, Y) is gp
        mean, var = gp.predict(Z[:7])
        assert mean.shape == (7, 2) and var.shape == (7, 2)
        assert np.all(var >= 0) and np.all(np.isfinite(mean))
        assert gp.noise_.shape == (2,) and np.all(gp.noise_ > 0)
        assert gp.n_inputs_ == 3 and gp.n_outputs_ == 2

    def test_init_stores_settings_only(self):
        gp = self.make(kernel="matern15", seed=3)
        assert not hasattr(gp, "hyper_")
        params = gp.get_params()
        assert params["kernel"] == "matern15" and params["seed"] == 3
        with pytest.raises(InputError, match="not fitted"):
            gp.predict(np.zeros((1, 3)))

    @pytest.mark.parametrize("kernel", ["se", "matern15"])
    def test_learns_smooth_function(self, kernel):
        Z, Y = smooth_data(n=120)
        Zt, Yt = smooth_data(n=200, seed=1, noise=0.0)
        gp = self.make(kernel=kernel).fit(Z, Y)
        mean, var = gp.predict(Zt)
        rmse = np.sqrt(np.mean((mean - Yt) ** 2, axis=0))
        assert np.all(rmse < 0.15 * Yt.std(axis=0)), rmse
        # calibrated: most true values inside the 95% band of the latent function plus noise
        inside = np.abs(mean - Yt) < 1.96 * np.sqrt(var + gp.noise_)
        assert inside.mean() > 0.8

    def test_latent_variance_excludes_noise(self):
        Z, Y = smooth_data(noise=0.3)
        gp = self.make(optimize=False, noise=0.5, length_scale=0.5).fit(Z, Y)
        _, var_far = gp.predict(np.full((1, 3), 50.0))
        sf2 = np.exp(gp.hyper_.log_sf2) * gp.hyper_.y_scale**2
        np.testing.assert_allclose(var_far[0], sf2, rtol=1e-6)  # prior variance, no noise term
        _, var_at = gp.predict(Z)
        assert np.all(np.median(var_at, axis=0) < gp.noise_)

    # -- GP mathematics --------------------------------------------------------------------------------
    def test_interpolates_as_noise_vanishes(self):
        Z, Y = smooth_data(n=25)
        errs, vars_ = [], []
        for noise in (1e-2, 1e-4, 1e-6, 1e-8):
            gp = self.make(optimize=False, noise=noise, length_scale=1.0).fit(Z, Y)
            mean, var = gp.predict(Z)
            errs.append(np.max(np.abs(mean - Y)))
            vars_.append(np.max(var / Y.var(axis=0)))
        assert all(a > b for a, b in zip(errs, errs[1:])), errs
        assert all(a > b for a, b in zip(vars_, vars_[1:])), vars_
        assert errs[-1] < 1e-4 * np.abs(Y).max() and vars_[-1] < 1e-5

    @pytest.mark.parametrize("optimize", [False, True])
    def test_rescaling_outputs_rescales_predictions(self, optimize):
        """Outputs are normalised, so an affine change of units changes nothing else. With fixed
        hyperparameters this holds to rounding; with fitted ones the optimiser may amplify the
        rounding of the normalised data slightly."""
        Z, Y = smooth_data()
        a, b = np.array([250.0, -0.01]), np.array([-3.0, 40.0])
        gp1 = self.make(optimize=optimize).fit(Z, Y)
        gp2 = self.make(optimize=optimize).fit(Z, a * Y + b)
        Zt, _ = smooth_data(n=30, seed=5)
        m1, v1 = gp1.predict(Zt)
        m2, v2 = gp2.predict(Zt)
        rtol = 1e-3 if optimize else 1e-9
        np.testing.assert_allclose((m2 - b) / a, m1, rtol=rtol, atol=rtol * np.abs(m1).max())
        np.testing.assert_allclose(v2 / a**2, v1, rtol=rtol, atol=rtol * v1.max())

    # -- save / load ----------------------------------------------------------------------------------
    @pytest.mark.parametrize("kernel", ["se", "matern15"])
    def test_save_load_bit_for_bit(self, tmp_path, kernel):
        Z, Y = smooth_data()
        gp = self.make(kernel=kernel).fit(Z, Y)
        meta = {"feature_map": "tracking", "input_names": ["v_y", "yaw_rate", "delta"], "output_names": ["a", "b"]}
        path = save_model(tmp_path / "m.h5", gp, meta)
        saved = load_model(path)
        assert saved.backend == self.backend_name and saved.feature_map == "tracking"
        assert saved.input_names == meta["input_names"] and saved.output_names == ["a", "b"]
        a1, a2 = gp.to_arrays(), saved.gp.to_arrays()
        assert a1.keys() == a2.keys()
        for k in a1:
            assert np.array_equal(a1[k], a2[k]), k
        Zt, _ = smooth_data(n=40, seed=9)
        for x, y in zip(gp.predict(Zt), saved.gp.predict(Zt)):
            assert np.array_equal(x, y)

    # -- training inputs --------------------------------------------------------------------------------
    def test_training_inputs_are_kept_in_data_units(self, tmp_path):
        """``train_inputs_`` is the ``Z`` given to fit, in its own units (not the normalised ones
        the backend works in), read-only, independent of the caller's array, and stored."""
        Z, Y = smooth_data(n=40)
        Z = Z * np.array([300.0, 0.01, 1.0]) + np.array([2000.0, -5.0, 0.0])  # far from mean 0, std 1
        gp = self.make()
        with pytest.raises(InputError, match="not fitted"):
            gp.train_inputs_
        gp.fit(Z, Y)
        kept = gp.train_inputs_
        assert np.array_equal(kept, Z)
        Z[0, 0] = -1.0  # the caller's array changes; the model's does not
        assert kept[0, 0] != -1.0
        with pytest.raises(ValueError):
            kept[0, 0] = 0.0
        loaded = load_model(save_model(tmp_path / "m.h5", gp)).gp
        assert np.array_equal(loaded.train_inputs_, gp.train_inputs_)
        assert np.array_equal(train_inputs(loaded), gp.train_inputs_)

    def test_model_without_training_inputs_loads_and_says_so(self):
        """A file from before the training inputs were stored predicts as before; asking for
        the inputs is an InputError naming them."""
        Z, Y = smooth_data(n=30)
        gp = self.make().fit(Z, Y)
        arrays = gp.to_arrays()
        del arrays[TRAIN_INPUTS]
        old = type(gp).from_arrays(arrays, gp.get_params())
        for x, y in zip(gp.predict(Z[:5]), old.predict(Z[:5])):
            assert np.array_equal(x, y)
        with pytest.raises(InputError, match="training inputs"):
            old.train_inputs_
        assert TRAIN_INPUTS not in old.to_arrays()

    def test_load_wrong_kind(self, tmp_path):
        p = write_artifact(tmp_path / "d.h5", Artifact("dataset", arrays={"Z": np.zeros((2, 3))}))
        with pytest.raises(ArtifactError, match="dataset"):
            load_model(p)

    # -- bad input ------------------------------------------------------------------------------------
    def test_empty_dataset(self):
        with pytest.raises(InputError, match="empty"):
            self.make().fit(np.zeros((0, 3)), np.zeros((0, 2)))

    def test_nan_is_rejected(self):
        Z, Y = smooth_data()
        Z[4, 1] = np.nan
        with pytest.raises(InputError, match="row 5, column 2"):  # rows and columns count from 1
            self.make().fit(Z, Y)
        Z, Y = smooth_data()
        Y[2, 0] = np.inf
        with pytest.raises(InputError, match="non-finite"):
            self.make().fit(Z, Y)
        gp = self.make().fit(*smooth_data())
        with pytest.raises(InputError):
            gp.predict(np.array([[0.0, np.nan, 0.0]]))

    def test_shape_errors(self):
        Z, Y = smooth_data()
        with pytest.raises(InputError, match="rows"):
            self.make().fit(Z, Y[:-1])
        gp = self.make().fit(Z, Y)
        with pytest.raises(InputError, match="expected inputs"):
            gp.predict(np.zeros((3, 2)))

    def test_constant_outputs(self):
        Z, _ = smooth_data()
        Y = np.column_stack([np.full(len(Z), 2.5), np.zeros(len(Z))])
        gp = self.make().fit(Z, Y)
        mean, var = gp.predict(Z[:5] + 0.1)
        np.testing.assert_allclose(mean, np.broadcast_to([2.5, 0.0], mean.shape), atol=1e-9)
        assert np.all(np.isfinite(var))

    def test_constant_input_column(self):
        Z, Y = smooth_data()
        Z[:, 2] = 1.0
        mean, var = self.make().fit(Z, Y).predict(Z[:4])
        assert np.all(np.isfinite(mean)) and np.all(np.isfinite(var))

    def test_duplicate_points(self):
        Z, Y = smooth_data(n=30)
        Z2, Y2 = np.concatenate([Z, Z, Z[:5]]), np.concatenate([Y, Y + 0.01, Y[:5]])
        for optimize in (True, False):
            gp = self.make(optimize=optimize, noise=1e-6).fit(Z2, Y2)
            mean, var = gp.predict(Z)
            assert np.all(np.isfinite(mean)) and np.all(var >= 0)
            assert np.max(np.abs(mean - (Y + 0.005))) < 0.1

    def test_single_point(self):
        mean, var = self.make().fit(np.ones((1, 3)), np.array([[1.0, -1.0]])).predict(np.ones((2, 3)))
        np.testing.assert_allclose(mean, [[1.0, -1.0]] * 2, atol=1e-6)
