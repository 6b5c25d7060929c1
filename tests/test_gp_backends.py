"""The shared GP contract for the built-in backends, and the registry."""

from __future__ import annotations

import pytest
from gp_contract import GPBackendContract

from gprace.errors import UnknownBackendError
from gprace.gp import make_gp


class TestExactGP(GPBackendContract):
    backend_name = "exact"


class TestSparseGP(GPBackendContract):
    backend_name = "sparse"
    settings = {"n_inducing": 40}


def test_unknown_backend_lists_available():
    with pytest.raises(UnknownBackendError) as err:
        make_gp("gpytorch-magic")
    msg = str(err.value)
    assert "gpytorch-magic" in msg and "exact" in msg and "sparse" in msg
    assert isinstance(err.value, KeyError)


def test_bad_setting_is_config_error():
    from gprace.errors import ConfigError

    with pytest.raises(ConfigError):
        make_gp("exact", n_inducing=3)
    with pytest.raises(ConfigError, match="kernel"):
        make_gp("sparse", kernel="rq").fit([[0.0]], [[1.0]])


def test_train_inputs_of_a_plugin_without_them_is_config_error():
    """A plugin class of its own (not derived from GPBackend) without ``train_inputs_``: the
    error names the backend and the attribute."""
    from gprace.errors import ConfigError
    from gprace.gp import train_inputs

    class Bare:
        NAME = "bare-gp"

    with pytest.raises(ConfigError, match="bare-gp.*train_inputs_"):
        train_inputs(Bare())
