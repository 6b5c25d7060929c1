"""Quality of a fitted GP, for any backend: has the fit silently degenerated?

:func:`fit_quality` takes a fitted model and reports per output

- ``noise``: the fitted noise variance in normalised units (share of the output's variance the fit
  calls noise; 1.0 means the output learned nothing),
- ``at_bounds``: hyperparameters within 1 % of their optimisation bounds
  (:data:`gprace.gp.base.BOUNDS`),
- ``heldout``: RMSE of the model's mean on held-out points, divided by the spread of those
  outputs (``sqrt(1 - R^2)``: 1.0 is no better than predicting their mean), next to ``reference``,
  the same figure for an exact GP fitted on a random subsample of the training data, with one
  kernel per output, or one for all when the model shares one (one shared kernel was up to 1.8
  times worse on single outputs than five at 300 points: a choice of model, not a degenerate fit).

An output is degenerate (``reasons``) when its held-out error is clearly worse than the
reference's (more than :data:`WORSE_RATIO` times it plus :data:`WORSE_MARGIN`), or when the
reference learns the output (held-out error below :data:`NOTHING_LEARNED`, i.e. it explains more
than 10 % of the variance) but the fit does not: its own error is at least that, its noise share is
at least :data:`NOISE_MAX`, or its hyperparameters make it a constant (every length scale at the
upper bound, or the signal variance at the lower one) or white noise (every length scale at the
lower bound). Where neither learns an output on held-out rows of the training data, the data carry
no signal for it: degenerate when the reference saw :data:`REFERENCE_POINTS` points, a ``warning``
when it saw fewer (a 100-point opponent dataset does not determine the speed and yaw-rate changes;
see docs/decisions.md). On a separate validation set, that case is a ``warning`` too: the training
data do not cover the validation set (an exploration dictionary of mostly closed-loop data judged on
random-track steps), which no retry of the fit can change. A
single length scale at its upper bound is no fault (that input does not matter for that output,
which is what ARD is for), nor is the noise at its lower bound (simulated data are noiseless).

:func:`checked_fit` fits, checks and retries a degenerate fit (other seed, start from the
reference's hyperparameters); a fit still degenerate is refused with :class:`FitError`.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from typing import Any, Sequence

import numpy as np

from gprace.errors import FitError
from gprace.gp.base import BOUNDS, GPBackend, make_gp

NOISE_MAX = 0.5
NOTHING_LEARNED = 0.95
WORSE_RATIO = 1.5
WORSE_MARGIN = 0.05
REFERENCE_POINTS = 300
HELDOUT_SHARE = 0.2  # without a validation set, this share of the data (at most HELDOUT_MAX) is held out
HELDOUT_MAX = 1000
BOUND_TOL = 0.01  # |log value - log bound| below this is "at the bound" (1 %)


@dataclass
class FitQuality:
    """The report of :func:`fit_quality` (JSON-friendly lists, one entry per output)."""

    outputs: list[str]
    noise: list[float]
    heldout: list[float]
    reference: list[float]
    reference_noise: list[float]
    at_bounds: list[list[str]]
    reasons: list[list[str]]  # why an output is degenerate (the fit is refused)
    warnings: list[list[str]]  # what the report cannot decide (too few points)
    heldout_points: int
    heldout_source: str
    reference_points: int
    attempts: int = 1
    retries: list[str] = field(default_factory=list)

    @property
    def degenerate(self) -> bool:
        return any(self.reasons)

    def to_json(self) -> str:
        return json.dumps(asdict(self))

    @classmethod
    def from_json(cls, text: str) -> "FitQuality":
        return cls(**json.loads(text))

    def problems(self) -> str:
        """``"dvx_opp: noise 0.99 >= 0.5; ..."``, empty when the fit is sound."""
        return "; ".join(f"{o}: {', '.join(r)}" for o, r in zip(self.outputs, self.reasons) if r)

    def cautions(self) -> str:
        """The warnings, like :meth:`problems`."""
        return "; ".join(f"{o}: {', '.join(r)}" for o, r in zip(self.outputs, self.warnings) if r)

    def rows(self) -> list[list[str]]:
        """One row per output for a console table (see :data:`COLUMNS`)."""
        return [[o, f"{n:.3g}", f"{h:.3f}", f"{r:.3f}", _short(b), ", ".join(x) or ("; ".join(w) or "ok")]
                for o, n, h, r, b, x, w in zip(self.outputs, self.noise, self.heldout, self.reference,
                                               self.at_bounds, self.reasons, self.warnings)]


def _short(bounds: list[str]) -> str:
    """``["ls(a) high", "ls(b) high", "noise low"]`` -> ``"ls high: a, b; noise low"``."""
    ls = {side: [b[3:b.index(")")] for b in bounds if b.startswith("ls(") and b.endswith(side)] for side in ("low", "high")}
    parts = [f"ls {side}: {', '.join(v)}" for side, v in ls.items() if v]
    return "; ".join(parts + [b for b in bounds if not b.startswith("ls(")]) or "-"


COLUMNS = ["output", "noise (norm.)", "held-out err", "exact subsample", "at bounds", "verdict"]


def _shares_kernel(gp: GPBackend) -> bool:
    """All outputs have the same hyperparameters (one kernel, e.g. ``shared_kernel=True``)."""
    h = gp.hyper_
    return h.p > 1 and bool(np.all(h.log_ls == h.log_ls[0]) and np.all(h.log_sf2 == h.log_sf2[0])
                            and np.all(h.log_sn2 == h.log_sn2[0]))


def _nrmse(mean: np.ndarray, Y: np.ndarray) -> np.ndarray:
    spread = np.maximum(Y.std(axis=0), 1e-300)
    return np.sqrt(np.mean((mean - Y) ** 2, axis=0)) / spread


def _bounds_hit(gp: GPBackend, o: int, inputs: Sequence[str]) -> list[str]:
    h = gp.hyper_
    out = []
    vals = [(f"ls({inputs[j]})", "length_scale", h.log_ls[o, j]) for j in range(h.d)]
    vals += [("signal", "signal_variance", h.log_sf2[o]), ("noise", "noise", h.log_sn2[o])]
    for label, key, v in vals:
        lo, hi = np.log(BOUNDS[key])
        if v - lo < BOUND_TOL:
            out.append(f"{label} low")
        elif hi - v < BOUND_TOL:
            out.append(f"{label} high")
    return out


def reference_gp(kernel: str, Z: np.ndarray, Y: np.ndarray, points: int = REFERENCE_POINTS,
                 seed: int = 0, shared: bool = False) -> tuple[GPBackend, np.ndarray]:
    """Exact GP (the given kernel; one for all outputs if ``shared``, as the model checked against
    it) on ``points`` random rows of (Z, Y); returns it and the indices of the rows it saw."""
    rng = np.random.default_rng(seed)
    idx = np.sort(rng.choice(len(Z), min(points, len(Z)), replace=False))
    ref = make_gp("exact", kernel=kernel, seed=seed, max_fit_points=len(idx), shared_kernel=shared).fit(Z[idx], Y[idx])
    return ref, idx


def fit_quality(gp: GPBackend, Z: np.ndarray, Y: np.ndarray, Z_val: np.ndarray, Y_val: np.ndarray,
                outputs: Sequence[str] | None = None, inputs: Sequence[str] | None = None,
                reference_points: int = REFERENCE_POINTS, seed: int = 0,
                reference: tuple[GPBackend, np.ndarray] | None = None, heldout_source: str = "held-out set",
                heldout_from_training: bool = False) -> FitQuality:
    """Quality report of ``gp`` fitted on (Z, Y), measured on held-out points ``(Z_val, Y_val)``
    (see the module docstring); ``heldout_from_training``: they were drawn from the same data (so
    an output nobody learns has no signal, rather than a held-out set the data do not cover).
    ``reference`` (from :func:`reference_gp` on (Z, Y)) skips refitting it."""
    Z, Y = np.asarray(Z, float), np.asarray(Y, float).reshape(len(Z), -1)
    Z_val, Y_val = np.asarray(Z_val, float), np.asarray(Y_val, float).reshape(len(Z_val), -1)
    p = Y.shape[1]
    outputs = list(outputs) if outputs is not None else [f"y{i}" for i in range(p)]
    inputs = list(inputs) if inputs is not None else [f"z{j}" for j in range(Z.shape[1])]
    ref, idx = reference if reference is not None else reference_gp(gp.kernel, Z, Y, reference_points, seed,
                                                                    shared=_shares_kernel(gp))
    held, refe = _nrmse(gp.predict(Z_val)[0], Y_val), _nrmse(ref.predict(Z_val)[0], Y_val)
    noise = np.exp(gp.hyper_.log_sn2)
    bounds = [_bounds_hit(gp, o, inputs) for o in range(p)]
    reasons, warnings = [], []
    for o in range(p):
        r, w = [], []
        learned = refe[o] < NOTHING_LEARNED  # the reference explains at least 10 % of the variance
        ref_txt = f"an exact GP on {len(idx)} points: {refe[o]:.2f}"
        if held[o] > WORSE_RATIO * refe[o] + WORSE_MARGIN:
            r.append(f"held-out error {held[o]:.3f} > {WORSE_RATIO} x {refe[o]:.3f} of an exact GP on {len(idx)} points")
        elif learned and held[o] >= NOTHING_LEARNED:
            r.append(f"learned nothing (held-out error {held[o]:.2f}; {ref_txt})")
        if learned and noise[o] >= NOISE_MAX:
            r.append(f"noise {noise[o]:.2f} >= {NOISE_MAX} ({ref_txt})")
        if learned and (all(f"ls({n}) high" in bounds[o] for n in inputs) or "signal low" in bounds[o]):
            r.append(f"constant: length scales or signal variance at their bounds ({ref_txt})")
        elif learned and all(f"ls({n}) low" in bounds[o] for n in inputs):
            r.append(f"white noise: every length scale at its lower bound ({ref_txt})")
        if not learned and held[o] >= NOTHING_LEARNED:
            txt = f"learned nothing (held-out error {held[o]:.2f}), nor did {ref_txt}"
            if len(idx) < REFERENCE_POINTS:
                w.append(txt + f": fewer than {REFERENCE_POINTS} points cannot tell a signal from noise")
            elif heldout_from_training:
                r.append(txt + ": no signal in the data")
            else:
                w.append(txt + ": the training data do not cover the held-out set")
        reasons.append(r)
        warnings.append(w)
    return FitQuality(outputs=outputs, noise=noise.tolist(), heldout=held.tolist(), reference=refe.tolist(),
                      reference_noise=np.exp(ref.hyper_.log_sn2).tolist(), at_bounds=bounds, reasons=reasons,
                      warnings=warnings, heldout_points=int(len(Z_val)), heldout_source=heldout_source,
                      reference_points=int(len(idx)))


def _hyper_settings(gp: GPBackend, Z: np.ndarray, Y: np.ndarray) -> dict[str, Any]:
    """The hyperparameters of a fitted ``gp`` as settings (``length_scale``, ``signal_variance``,
    ``noise``) in the normalised units of (Z, Y), which may differ from the data it was fitted on."""
    from gprace.gp.base import fit_scalers

    h = gp.hyper_
    z_mean, z_scale, y_mean, y_scale = fit_scalers(Z, Y)
    ls = np.exp(h.log_ls) * h.z_scale / z_scale
    ratio = (h.y_scale / y_scale) ** 2
    clip = lambda a, k: np.clip(a, *BOUNDS[k])  # noqa: E731
    return {"length_scale": clip(ls, "length_scale"), "signal_variance": clip(np.exp(h.log_sf2) * ratio, "signal_variance"),
            "noise": clip(np.exp(h.log_sn2) * ratio, "noise")}


def checked_fit(backend: str, settings: dict[str, Any], Z: np.ndarray, Y: np.ndarray,
                Z_val: np.ndarray | None = None, Y_val: np.ndarray | None = None,
                outputs: Sequence[str] | None = None, inputs: Sequence[str] | None = None,
                attempts: int = 3, what: str = "GP") -> tuple[GPBackend, FitQuality]:
    """Fit ``make_gp(backend, **settings)`` on (Z, Y) and check it with :func:`fit_quality`.

    Held-out points: ``(Z_val, Y_val)``; without them :data:`HELDOUT_SHARE` of the rows is held
    out of the checked fit, and the returned model is then refitted on all rows with the checked
    hyperparameters (fixed). A degenerate fit is retried (``attempts`` in all) with another seed,
    starting from the reference exact GP's hyperparameters; the last of three or more attempts
    keeps those hyperparameters fixed (the backend's posterior on all data with the reference's
    kernel; a ``min_noise`` setting still bounds the noise). If every attempt is degenerate,
    :class:`FitError` names the outputs and why, and no model is returned.
    """
    Z, Y = np.asarray(Z, float), np.asarray(Y, float).reshape(len(Z), -1)
    seed = int(settings.get("seed", 0))
    Zf, Yf, source = Z, Y, "held-out set"
    if Z_val is None:
        perm = np.random.default_rng(seed + 1).permutation(len(Z))
        k = max(1, min(HELDOUT_MAX, int(round(HELDOUT_SHARE * len(Z)))))
        Z_val, Y_val, Zf, Yf = Z[perm[:k]], Y[perm[:k]], Z[np.sort(perm[k:])], Y[np.sort(perm[k:])]
        source = f"{k} rows held out of the checked fit, then refitted on all {len(Z)} with its hyperparameters"
    ref = reference_gp(str(settings.get("kernel", "se")), Zf, Yf, REFERENCE_POINTS, seed,
                       shared=bool(settings.get("shared_kernel", False)))
    retries: list[str] = []
    attempts = attempts if settings.get("optimize", True) else 1  # fixed hyperparameters: nothing to retry
    for a in range(attempts):
        s = dict(settings)
        if a > 0:  # another seed, from the reference's optimum; the last attempt keeps that optimum
            start = _hyper_settings(ref[0], Zf, Yf)
            start["noise"] = np.maximum(start["noise"], float(settings.get("min_noise", 0.0)))
            s.update(seed=seed + 1000 * a, **start)
            if a == attempts - 1 and attempts > 2:
                s["optimize"] = False
        gp = make_gp(backend, **s).fit(Zf, Yf)
        q = fit_quality(gp, Zf, Yf, Z_val, Y_val, outputs, inputs, seed=seed, reference=ref, heldout_source=source,
                        heldout_from_training=Zf is not Z)
        q.attempts, q.retries = a + 1, list(retries)
        if not q.degenerate:
            if Zf is not Z:
                gp = make_gp(backend, **{**s, "optimize": False, **_hyper_settings(gp, Z, Y)}).fit(Z, Y)
            return gp, q
        retries.append(q.problems())
    raise FitError(f"{what}: {backend} GP fit degenerate after {attempts} attempts ({q.problems()}); "
                   "refused, nothing raced with it")
