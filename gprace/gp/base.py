"""The GP backend contract, normalisation, hyperparameters and model files.

A backend is a small class with ``NAME`` and four private hooks; :class:`GPBackend` does the
rest (input checks, scalers, the estimator contract, save/load):

- ``__init__`` stores settings only (scikit-learn estimator contract); learned state ends in ``_``;
- ``fit(Z (n, d), Y (n, p)) -> self``; ``predict(Z (m, d)) -> (mean (m, p), var (m, p))`` where
  ``var`` is the variance of the LATENT function (no noise term; add :attr:`noise_` for the
  variance of a new measurement);
- one GP per output, each with its own ARD length scales, signal variance and noise variance,
  fitted on normalised data (inputs and outputs shifted to mean 0 and scaled to standard
  deviation 1; a constant column keeps scale 1). Hyperparameters live in log space, in the
  normalised units, within :data:`BOUNDS`.
- ``train_inputs_``: the training inputs ``(n, d)`` in DATA units (the units of the ``Z`` given
  to ``fit``, not the normalised units the backend works in), read-only. Kept by the base class
  for every backend and stored with the model (array ``train/Z``), so a loaded model has them
  too; what is built from "the data the GP has seen" (the exploration candidates of Algorithm 1)
  reads them here, never from a backend's own (normalised, or inducing) points. A model file
  written before they were stored loads and predicts, and this property raises InputError.
- ``to_arrays()`` / ``from_arrays(arrays, params)``: the full learned state as named float
  arrays, so models are stored in HDF5 without pickle; :func:`save_model` / :func:`load_model`
  wrap them as an artifact of kind ``gp_model``.

Initial (or, with ``optimize=False``, fixed) hyperparameters come from the settings
``length_scale``, ``signal_variance`` and ``noise``: scalars, or arrays broadcast to ``(p, d)``
and ``(p,)``, in normalised units.
"""

from __future__ import annotations

import inspect
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from gprace.errors import ArtifactError, ConfigError, InputError, SolverError, at_row
from gprace.gp.kernels import check_kernel, kernel

ARTIFACT_KIND = "gp_model"
TRAIN_INPUTS = "train/Z"
"""Name of the training inputs (data units) among a model's arrays (absent in older files)."""

BOUNDS: dict[str, tuple[float, float]] = {
    "length_scale": (1e-2, 1e2),
    "signal_variance": (1e-4, 1e2),
    "noise": (1e-6, 10.0),
}
"""Bounds of the hyperparameters during optimisation (normalised units)."""


# --------------------------------------------------------------------------------------------
# data checks
# --------------------------------------------------------------------------------------------
def check_training_data(Z: Any, Y: Any, where: str = "training data") -> tuple[np.ndarray, np.ndarray]:
    """Validate and return ``Z (n, d)``, ``Y (n, p)`` as float arrays (``Y (n,)`` becomes ``(n, 1)``)."""
    try:
        Z = np.asarray(Z, dtype=float)
        Y = np.asarray(Y, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{where}: inputs and outputs must be numeric arrays") from None
    if Y.ndim == 1:
        Y = Y[:, None]
    if Z.ndim != 2 or Y.ndim != 2:
        raise InputError(f"{where}: expected Z (n, d) and Y (n, p), got {Z.shape} and {Y.shape}")
    if Z.shape[0] == 0:
        raise InputError(f"{where}: empty dataset (0 points)")
    if Z.shape[0] != Y.shape[0]:
        raise InputError(f"{where}: Z has {Z.shape[0]} rows but Y has {Y.shape[0]}")
    if Z.shape[1] == 0 or Y.shape[1] == 0:
        raise InputError(f"{where}: need at least one input and one output column, got {Z.shape}, {Y.shape}")
    _check_finite(Z, f"{where}: input Z")
    _check_finite(Y, f"{where}: output Y")
    return Z, Y


def _read_only(A: np.ndarray) -> np.ndarray:
    A.setflags(write=False)
    return A


def _train_inputs_of(arrays: dict[str, np.ndarray], d: int) -> np.ndarray | None:
    """The stored training inputs (None in a file from before they were kept); a wrong shape is
    an ArtifactError naming the array."""
    if TRAIN_INPUTS not in arrays:
        return None
    Z = np.array(arrays[TRAIN_INPUTS], dtype=float)
    if Z.ndim != 2 or Z.shape[1] != d:
        raise ArtifactError(f"GP state: {TRAIN_INPUTS} has shape {Z.shape}, expected (n, {d})")
    return _read_only(Z)


def _check_finite(A: np.ndarray, what: str) -> None:
    bad = ~np.isfinite(A)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise InputError(f"{what} has a non-finite value ({A[i, j]}) at {at_row(i + 1)}, column {j + 1}")


# --------------------------------------------------------------------------------------------
# hyperparameters and scalers
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class GPHyper:
    """Scalers and per-output hyperparameters of a fitted GP (log values, normalised units).

    ``z_mean, z_scale (d,)``, ``y_mean, y_scale (p,)``, ``log_ls (p, d)``, ``log_sf2 (p,)``,
    ``log_sn2 (p,)``. Shared by the backends and by the data selection, which uses fixed
    hyperparameters.
    """

    kernel: str
    z_mean: np.ndarray
    z_scale: np.ndarray
    y_mean: np.ndarray
    y_scale: np.ndarray
    log_ls: np.ndarray
    log_sf2: np.ndarray
    log_sn2: np.ndarray

    ARRAYS: ClassVar[tuple[str, ...]] = ("z_mean", "z_scale", "y_mean", "y_scale", "log_ls", "log_sf2", "log_sn2")

    @property
    def d(self) -> int:
        return int(self.z_mean.shape[0])

    @property
    def p(self) -> int:
        return int(self.y_mean.shape[0])

    def ls(self, o: int) -> np.ndarray:
        return np.exp(self.log_ls[o])

    def sf2(self, o: int) -> float:
        return float(np.exp(self.log_sf2[o]))

    def sn2(self, o: int) -> float:
        return float(np.exp(self.log_sn2[o]))

    def zn(self, Z: np.ndarray) -> np.ndarray:
        return (Z - self.z_mean) / self.z_scale

    def yn(self, Y: np.ndarray) -> np.ndarray:
        return (Y - self.y_mean) / self.y_scale

    def k(self, o: int, A: np.ndarray, B: np.ndarray) -> np.ndarray:
        """Kernel of output ``o`` between normalised inputs."""
        return kernel(self.kernel, A, B, self.ls(o), self.sf2(o))

    def groups(self) -> list[list[int]]:
        """Outputs with identical hyperparameters (one kernel, so one set of factors), in order."""
        groups: list[list[int]] = []
        for o in range(self.p):
            for g in groups:
                q = g[0]
                if (np.array_equal(self.log_ls[q], self.log_ls[o]) and self.log_sf2[q] == self.log_sf2[o]
                        and self.log_sn2[q] == self.log_sn2[o]):
                    g.append(o)
                    break
            else:
                groups.append([o])
        return groups

    def theta(self, o: int) -> np.ndarray:
        """``[log ls..., log sf2, log sn2]`` of output ``o``."""
        return np.concatenate([self.log_ls[o], [self.log_sf2[o], self.log_sn2[o]]])

    def to_arrays(self, prefix: str = "") -> dict[str, np.ndarray]:
        return {prefix + k: np.asarray(getattr(self, k), dtype=float) for k in self.ARRAYS}

    @classmethod
    def from_arrays(cls, kernel_name: str, arrays: dict[str, np.ndarray], prefix: str = "") -> "GPHyper":
        try:
            vals = {k: np.asarray(arrays[prefix + k], dtype=float) for k in cls.ARRAYS}
        except KeyError as exc:
            raise InputError(f"GP state: missing array {exc.args[0]!r}") from None
        return cls(kernel=check_kernel(kernel_name), **vals)


def fit_scalers(Z: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, ...]:
    """Column means and standard deviations; a (near) constant column keeps scale 1."""
    z_mean, y_mean = Z.mean(axis=0), Y.mean(axis=0)
    z_scale, y_scale = Z.std(axis=0), Y.std(axis=0)
    z_scale = np.where(z_scale > 1e-12 * np.maximum(1.0, np.abs(z_mean)), z_scale, 1.0)
    y_scale = np.where(y_scale > 1e-12 * np.maximum(1.0, np.abs(y_mean)), y_scale, 1.0)
    return z_mean, z_scale, y_mean, y_scale


def _broadcast(value: Any, shape: tuple[int, ...], name: str) -> np.ndarray:
    try:
        a = np.broadcast_to(np.asarray(value, dtype=float), shape).copy()
    except ValueError:
        raise ConfigError(f"GP setting {name}: cannot broadcast {np.shape(value)} to {shape}") from None
    if not np.all(np.isfinite(a)) or np.any(a <= 0):
        raise ConfigError(f"GP setting {name}: values must be positive and finite")
    return a


def _own_parameters(klass: type) -> list[inspect.Parameter]:
    """The named constructor arguments ``klass`` itself declares (none if it has no ``__init__``)."""
    if "__init__" not in klass.__dict__ or klass is object:
        return []
    return [p for p in inspect.signature(klass.__init__).parameters.values()
            if p.name != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]


# --------------------------------------------------------------------------------------------
# backend base class
# --------------------------------------------------------------------------------------------
class GPBackend(ABC):
    """Abstract GP backend (see the module docstring for the contract)."""

    NAME: ClassVar[str] = ""

    def __init__(
        self,
        kernel: str = "se",
        noise: Any = 1e-2,
        optimize: bool = True,
        seed: int = 0,
        length_scale: Any = 1.0,
        signal_variance: Any = 1.0,
    ) -> None:
        self.kernel, self.noise, self.optimize = kernel, noise, optimize
        self.seed, self.length_scale, self.signal_variance = seed, length_scale, signal_variance

    # -- settings ----------------------------------------------------------------------------
    @classmethod
    def _parameters(cls) -> dict[str, inspect.Parameter]:
        """The settings of a backend by name, the base class's first: a backend's ``__init__``
        declares its own and passes the base settings on (``*args, **base``), so each is written
        once; the most derived declaration gives the default."""
        names = [p.name for klass in reversed(cls.__mro__) for p in _own_parameters(klass)]
        found: dict[str, inspect.Parameter] = {}
        for klass in cls.__mro__:
            for p in _own_parameters(klass):
                found.setdefault(p.name, p)
        return {name: found[name] for name in dict.fromkeys(names)}

    def get_params(self) -> dict[str, Any]:
        """Settings as JSON-friendly values (arrays become lists)."""
        out = {}
        for name in self._parameters():
            v = getattr(self, name)
            out[name] = np.asarray(v).tolist() if isinstance(v, np.ndarray) else v
        return out

    def __repr__(self) -> str:
        return f"{type(self).__name__}({', '.join(f'{k}={v!r}' for k, v in self.get_params().items())})"

    # -- estimator contract --------------------------------------------------------------------
    def fit(self, Z: Any, Y: Any) -> "GPBackend":
        """Fit hyperparameters (if ``optimize``) and the posterior. Returns ``self``."""
        check_kernel(self.kernel)
        Z, Y = check_training_data(Z, Y)
        n, d = Z.shape
        p = Y.shape[1]
        z_mean, z_scale, y_mean, y_scale = fit_scalers(Z, Y)
        Zn = (Z - z_mean) / z_scale
        Yn = (Y - y_mean) / y_scale
        log_ls = np.log(_broadcast(self.length_scale, (p, d), "length_scale"))
        log_sf2 = np.log(_broadcast(self.signal_variance, (p,), "signal_variance"))
        log_sn2 = np.log(_broadcast(self.noise, (p,), "noise"))
        self._prepare(Zn, Yn)
        if self.optimize:
            lo = {k: np.log(v[0]) for k, v in BOUNDS.items()}
            hi = {k: np.log(v[1]) for k, v in BOUNDS.items()}
            log_ls = np.clip(log_ls, lo["length_scale"], hi["length_scale"])
            log_sf2 = np.clip(log_sf2, lo["signal_variance"], hi["signal_variance"])
            log_sn2 = np.clip(log_sn2, lo["noise"], hi["noise"])
            log_ls, log_sf2, log_sn2 = self._fit_hyperparameters(Zn, Yn, log_ls, log_sf2, log_sn2)
        self.hyper_ = GPHyper(self.kernel, z_mean, z_scale, y_mean, y_scale,
                              np.asarray(log_ls, float), np.asarray(log_sf2, float), np.asarray(log_sn2, float))
        self.n_train_ = n
        self._train_inputs = _read_only(Z.copy())
        self._fit_posterior(Zn, Yn)
        return self

    def predict(self, Z: Any) -> tuple[np.ndarray, np.ndarray]:
        """Posterior mean and latent variance, each ``(m, p)``, in the units of ``Y``."""
        h = self._fitted()
        try:
            Z = np.asarray(Z, dtype=float)
        except (TypeError, ValueError):
            raise InputError("GP predict: inputs must be a numeric array") from None
        if Z.ndim == 1 and Z.shape[0] == h.d:
            Z = Z[None, :]
        if Z.ndim != 2 or Z.shape[1] != h.d:
            raise InputError(f"GP predict: expected inputs (m, {h.d}), got {Z.shape}")
        _check_finite(Z, "GP predict: input Z")
        return self._in_units(self._predict_normalised, Z)

    def fast_predict(self, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`predict` for many small queries of trusted inputs (finite ``(m, d)`` floats, not
        checked): the same mean; a variance never below the latent variance of :meth:`predict`
        (a backend's ``_fast_normalised`` documents how far above it may be). Used by the
        opponent rollouts."""
        return self._in_units(self._fast_normalised, np.asarray(Z, dtype=float))

    def fast_mean(self, Z: np.ndarray) -> np.ndarray:
        """The mean of :meth:`fast_predict` alone (a backend may skip the variance's work)."""
        h = self.hyper_
        return self._fast_mean_normalised((np.asarray(Z, dtype=float) - h.z_mean) / h.z_scale) * h.y_scale + h.y_mean

    def kernel_form(self):
        """The posterior as a :class:`~gprace.gp.fastkernel.KernelForm` for compiled predictors,
        or None: a backend without one, or outputs with more than one kernel."""
        return None

    def _form(self, pts, wT: np.ndarray, variance: str, V: np.ndarray):
        """:meth:`kernel_form` of a fitted one-kernel backend from its points, weights and
        variance matrix (None with more than one kernel)."""
        from gprace.gp.fastkernel import KernelForm

        h = self._fitted()
        if len(h.groups()) != 1:
            return None
        return KernelForm(h.kernel, pts, np.ascontiguousarray(wT, dtype=float), float(h.sf2(0)), variance,
                          np.ascontiguousarray(V, dtype=float), np.asarray(h.z_mean, float),
                          np.asarray(h.z_scale * h.ls(0), float), np.asarray(h.y_mean, float),
                          np.asarray(h.y_scale, float))

    def _in_units(self, predict_normalised, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        h = self.hyper_
        mean_n, var_n = predict_normalised((Z - h.z_mean) / h.z_scale)
        np.maximum(var_n, 0.0, out=var_n)
        return mean_n * h.y_scale + h.y_mean, var_n * h.y_scale**2

    @property
    def noise_(self) -> np.ndarray:
        """Noise variance per output ``(p,)`` in the units of ``Y`` squared."""
        h = self._fitted()
        return np.exp(h.log_sn2) * h.y_scale**2

    @property
    def signal_(self) -> np.ndarray:
        """Prior variance of the latent function per output ``(p,)`` in the units of ``Y`` squared
        (what the latent variance of :meth:`predict` tends to far from the data)."""
        h = self._fitted()
        return np.exp(h.log_sf2) * h.y_scale**2

    @property
    def train_inputs_(self) -> np.ndarray:
        """Training inputs ``(n, d)`` in data units (read-only; see the module docstring)."""
        self._fitted()
        Z = getattr(self, "_train_inputs", None)
        if Z is None:
            raise InputError(f"{type(self).__name__}: this model file has no training inputs (written before "
                             "they were stored); retrain it to use them")
        return Z

    @property
    def n_outputs_(self) -> int:
        return self._fitted().p

    @property
    def n_inputs_(self) -> int:
        return self._fitted().d

    def _fitted(self) -> GPHyper:
        h = getattr(self, "hyper_", None)
        if h is None:
            raise InputError(f"{type(self).__name__} is not fitted; call fit() or load a model first")
        return h

    # -- state -------------------------------------------------------------------------------
    def to_arrays(self) -> dict[str, np.ndarray]:
        """All learned state as named float arrays (exact copies: a round trip is bit for bit)."""
        h = self._fitted()
        out = h.to_arrays("hyper/")
        out["n_train"] = np.asarray(self.n_train_)
        if getattr(self, "_train_inputs", None) is not None:
            out[TRAIN_INPUTS] = np.array(self._train_inputs)
        for k, v in self._state_arrays().items():
            out["state/" + k] = np.asarray(v)
        return out

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], params: dict[str, Any]) -> "GPBackend":
        try:
            gp = cls(**params)
        except TypeError as exc:
            raise InputError(f"GP model: settings do not fit backend {cls.NAME!r}: {exc}") from None
        gp.hyper_ = GPHyper.from_arrays(gp.kernel, arrays, "hyper/")
        gp.n_train_ = int(arrays.get("n_train", 0))
        gp._train_inputs = _train_inputs_of(arrays, gp.hyper_.d)
        state = {k[len("state/"):]: v for k, v in arrays.items() if k.startswith("state/")}
        gp._load_state(state)
        return gp

    # -- hooks for backends --------------------------------------------------------------------
    def _prepare(self, Zn: np.ndarray, Yn: np.ndarray) -> None:
        """Called before hyperparameter fitting (e.g. to choose inducing points)."""

    @abstractmethod
    def _fit_hyperparameters(
        self, Zn: np.ndarray, Yn: np.ndarray, log_ls: np.ndarray, log_sf2: np.ndarray, log_sn2: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Maximise the (approximate) marginal likelihood from the given initial log values.

        Shapes ``(p, d)``, ``(p,)``, ``(p,)``; returns the optimised values, within :data:`BOUNDS`.
        """

    @abstractmethod
    def _fit_posterior(self, Zn: np.ndarray, Yn: np.ndarray) -> None:
        """Cache what prediction needs, with ``self.hyper_`` set."""

    @abstractmethod
    def _predict_normalised(self, Zn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean and latent variance ``(m, p)`` in normalised units."""

    def _fast_normalised(self, Zn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`fast_predict` in normalised units; default: :meth:`_predict_normalised`."""
        return self._predict_normalised(Zn)

    def _fast_mean_normalised(self, Zn: np.ndarray) -> np.ndarray:
        """:meth:`fast_mean` in normalised units; default: the mean of :meth:`_fast_normalised`."""
        return self._fast_normalised(Zn)[0]

    @abstractmethod
    def _state_arrays(self) -> dict[str, np.ndarray]:
        """Backend-specific learned arrays (besides the hyperparameters)."""

    @abstractmethod
    def _load_state(self, state: dict[str, np.ndarray]) -> None:
        """Restore from :meth:`_state_arrays` output; ``self.hyper_`` is already set."""


def best_start(kernel_name: str, theta0: np.ndarray, Z: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """The better start for hyperparameter optimisation: ``theta0`` or the default
    ``[log 1 (ls), log 1 (sf2), log 1e-2 (sn2)]``, judged by the exact log marginal likelihood on
    ``(Z, Y)`` (``Y (n,)`` or ``(n, q)`` summed over columns).

    A start at an extreme (say noise at its lower bound with duplicate inputs) can lead L-BFGS-B
    into the broad optimum that explains everything as noise; two likelihood evaluations avoid it.
    """
    from gprace.gp.objectives import exact_lml

    d = Z.shape[1]
    default = np.concatenate([np.zeros(d), [0.0, np.log(1e-2)]])
    if np.allclose(theta0, default):
        return theta0
    Y = Y.reshape(len(Y), -1)
    scores = []
    for th in (theta0, default):
        try:
            scores.append(sum(exact_lml(kernel_name, th, Z, Y[:, i])[0] for i in range(Y.shape[1])))
        except (SolverError, np.linalg.LinAlgError):  # an unusable start (not positive definite) scores worst
            scores.append(-np.inf)
    return theta0 if scores[0] >= scores[1] else default


def optimisation_bounds(d: int) -> list[tuple[float, float]]:
    """L-BFGS-B bounds for ``theta = [log ls (d), log sf2, log sn2]``."""
    b = [tuple(np.log(BOUNDS["length_scale"]))] * d
    b.append(tuple(np.log(BOUNDS["signal_variance"])))
    b.append(tuple(np.log(BOUNDS["noise"])))
    return [(float(lo), float(hi)) for lo, hi in b]


# --------------------------------------------------------------------------------------------
# model files
# --------------------------------------------------------------------------------------------
@dataclass
class SavedGP:
    """A GP read from a ``gp_model`` artifact, with what it was trained on."""

    gp: GPBackend
    backend: str
    feature_map: str
    input_names: list[str]
    output_names: list[str]
    attrs: dict[str, Any] = field(default_factory=dict)


def train_inputs(gp: Any) -> np.ndarray:
    """``gp.train_inputs_`` (``(n, d)``, data units) of any backend; a ConfigError naming the
    backend if it has none (a plugin class that neither derives from :class:`GPBackend` nor
    provides the attribute)."""
    try:
        Z = gp.train_inputs_
    except AttributeError:
        name = getattr(gp, "NAME", "") or type(gp).__name__
        raise ConfigError(f"GP backend {name!r} does not expose its training inputs (train_inputs_)") from None
    return np.asarray(Z, dtype=float)


def make_gp(backend: str, **settings: Any) -> GPBackend:
    """Instantiate a registered backend by name (``exact``, ``sparse`` or a plugin)."""
    from gprace.registry import gps

    cls = gps.get(backend)
    _check_types(backend, cls, settings)
    try:
        return cls(**settings)
    except TypeError as exc:
        raise ConfigError(f"GP backend {backend!r}: {exc}") from None


def _check_types(backend: str, cls: type, settings: dict[str, Any]) -> None:
    """Text where the default is a number or a boolean (``--opt max_fit_points=abc``) is an error
    naming the option; arrays and numbers pass (``length_scale`` may be per input)."""
    if isinstance(cls, type) and issubclass(cls, GPBackend):
        params, takes_any = cls._parameters(), False
    else:  # a plugin class of its own: its constructor's signature
        sig = inspect.signature(cls.__init__).parameters
        params = {k: p for k, p in sig.items() if k != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)}
        takes_any = any(p.kind == p.VAR_KEYWORD for p in sig.values())
    known = list(params)
    unknown = [k for k in settings if k not in known]
    if unknown and not takes_any:
        raise ConfigError(f"GP backend {backend!r}: unknown option {', '.join(unknown)}; available: {', '.join(known)}")
    for key, value in settings.items():
        default = params[key].default if key in params else None
        if isinstance(default, (bool, int, float)) and isinstance(value, str):
            what = "true or false" if isinstance(default, bool) else "a number"
            raise ConfigError(f"GP backend {backend!r}: option {key} expects {what}, got {value!r}")


def save_model(path: str | Path, gp: GPBackend, meta: dict[str, Any] | None = None,
               config_hash: str = "", seed: int | None = None) -> Path:
    """Write a fitted GP as an artifact of kind ``gp_model``.

    ``meta`` may hold ``feature_map`` (str), ``input_names`` and ``output_names`` (lists of str)
    and any other scalar or string attributes.
    """
    from gprace.io.artifacts import Artifact, write_artifact

    h = gp._fitted()
    meta = dict(meta or {})
    attrs = {
        "backend": gp.NAME or type(gp).__name__,
        "kernel": gp.kernel,
        "params": gp.get_params(),
        "feature_map": str(meta.pop("feature_map", "")),
        "input_names": [str(x) for x in meta.pop("input_names", [f"z{i}" for i in range(h.d)])],
        "output_names": [str(x) for x in meta.pop("output_names", [f"y{i}" for i in range(h.p)])],
    }
    attrs.update(meta)
    art = Artifact(ARTIFACT_KIND, arrays=gp.to_arrays(), attrs=attrs, config_hash=config_hash,
                   seed=int(gp.seed if seed is None else seed))
    return write_artifact(path, art)


def load_model(path: str | Path) -> SavedGP:
    """Read a ``gp_model`` artifact (ArtifactError if the file is of another kind).

    The learned arrays are stored under nested names (``hyper/<name>``, ``state/<name>``), which
    :func:`~gprace.io.artifacts.read_artifact` returns under their full names.
    """
    from gprace.registry import gps
    from gprace.io.artifacts import read_artifact

    art = read_artifact(path, ARTIFACT_KIND)
    attrs, arrays = dict(art.attrs), art.arrays
    try:
        backend = str(attrs.pop("backend"))
        params = dict(attrs.pop("params"))
        input_names = [str(x) for x in attrs.pop("input_names")]
        output_names = [str(x) for x in attrs.pop("output_names")]
    except (KeyError, ValueError, TypeError) as exc:
        raise ArtifactError(f"{path}: GP model attributes are incomplete ({exc})") from None
    cls = gps.get(backend)
    gp = cls.from_arrays(arrays, params)
    return SavedGP(gp=gp, backend=backend, feature_map=str(attrs.pop("feature_map", "")),
                   input_names=list(input_names), output_names=list(output_names), attrs=attrs)
