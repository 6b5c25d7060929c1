"""A fitted GP as a portable model for a controller outside gprace: one HDF5 file and a JSON card.

The HDF5 file holds plain arrays, no gprace artifact layout (datasets at the root):

==================  =========  ==============================================================
``Z``               (M, d)     the dictionary, inputs in their physical units
``z_mean, z_scale`` (d,)       input normalisation: ``zn = (z - z_mean) / z_scale``
``y_mean, y_scale`` (p,)       output normalisation
``length_scale``    (p, d)     per output, in normalised input units
``signal_variance`` (p,)       ``sf2`` per output, normalised output units
``noise_variance``  (p,)       ``sn2`` per output, normalised output units
``alpha``           (M, p)     ``(K + sn2 I)^-1 (Y - y_mean) / y_scale``
``cholesky``        (g, M, M)  lower factor ``L_g`` of ``K + sn2 I`` of each factor group
``group``           (p,)       the factor group of each output
``var_scale``       (p,)       calibration of the variance (1 = the GP's own)
==================  =========  ==============================================================

The card (JSON) names the inputs in order with units, the outputs with units and what they are,
the kernel, the formulas below, the controller step the outputs are residuals of, the vehicle and
the training provenance. For a query ``z`` and output ``o`` (kernel ``se``; ``matern15`` replaces
``exp(-r^2/2)`` by ``(1 + sqrt3 r) exp(-sqrt3 r)``)::

    zn      = (z - z_mean) / z_scale
    r_i^2   = sum_j ((zn_j - Zn_ij) / length_scale_oj)^2        Zn = (Z - z_mean) / z_scale
    k_i     = signal_variance_o * exp(-r_i^2 / 2)
    mean_o  = y_mean_o + y_scale_o * sum_i k_i alpha_io
    v       = solve(L_group(o), k)                               (forward substitution)
    var_o   = var_scale_o * y_scale_o^2 * (signal_variance_o - v.v)          latent
    var_o  += var_scale_o * y_scale_o^2 * noise_variance_o                   a new measurement

:class:`PortableGP` is the reference evaluator in plain numpy (it imports nothing from gprace), so
a team can copy it next to their controller; a test checks it reproduces gprace's predictions.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

PORTABLE_VERSION = 1
UNITS = {"v_x": "m/s", "v_y": "m/s", "yaw_rate": "rad/s", "delta": "rad", "a_x": "m/s^2",
         "dv_y_dt": "m/s^2", "dyaw_rate_dt": "rad/s^2"}
MEANING = {
    "v_x": "longitudinal velocity of the body at the centre of gravity",
    "v_y": "lateral velocity of the body at the centre of gravity (left +)",
    "yaw_rate": "yaw rate (counter-clockwise +)",
    "delta": "steering angle command at the front wheels (left +)",
    "a_x": "longitudinal acceleration command",
}
OUTPUT_MEANING = {
    "tracking": "one-step error of {name} over one controller step dt: measured minus the nominal model's step",
    "planning": "error of {name}: the measured derivative minus the nominal model's",
}


def export_gp(predictor, h5_path: str | Path, card_path: str | Path, *, dt: float | None = None, step: str = "",
              vehicle=None, provenance: dict | None = None) -> dict:
    """Write the fitted exact GP of ``predictor`` (a :class:`gprace.timetrial.learning.GPPredictor`)
    as the portable HDF5 file and its JSON card; returns the card."""
    import h5py

    from gprace import __version__
    from gprace.errors import InputError
    from gprace.io.artifacts import write_text_atomic

    gp = predictor.gp
    if not hasattr(gp, "L_") or not hasattr(gp, "alpha_"):
        raise InputError(f"GP export: backend {gp.NAME!r} has no cached factor; only the exact GP exports")
    h = gp.hyper_
    groups = gp._groups()
    group_of = np.empty(h.p, dtype=np.int64)
    for gi, g in enumerate(groups):
        group_of[g] = gi
    h5_path, card_path = Path(h5_path), Path(card_path)
    tmp = h5_path.with_name(f".{h5_path.name}.tmp")
    arrays = {
        "Z": gp.Z_ * h.z_scale + h.z_mean, "z_mean": h.z_mean, "z_scale": h.z_scale, "y_mean": h.y_mean,
        "y_scale": h.y_scale, "length_scale": np.exp(h.log_ls), "signal_variance": np.exp(h.log_sf2),
        "noise_variance": np.exp(h.log_sn2), "alpha": gp.alpha_, "cholesky": gp.L_, "group": group_of,
        "var_scale": np.asarray(predictor.var_scale, float),
    }
    with h5py.File(tmp, "w") as f:
        for k, v in arrays.items():
            f.create_dataset(k, data=np.asarray(v))
        f.attrs["format"] = "gprace portable GP"
        f.attrs["version"] = PORTABLE_VERSION
        f.attrs["kernel"] = h.kernel
        f.attrs["inputs"] = json.dumps(list(predictor.inputs))
    tmp.replace(h5_path)
    outputs = _outputs(predictor)
    kind = predictor.kind if predictor.kind in OUTPUT_MEANING else "tracking"
    card = {
        "format": "gprace portable GP", "version": PORTABLE_VERSION, "gprace_version": __version__,
        "file": h5_path.name, "sha256": hashlib.sha256(h5_path.read_bytes()).hexdigest(),
        "kind": predictor.kind, "kernel": h.kernel, "dictionary_size": int(gp.Z_.shape[0]),
        "inputs": [{"name": n, "unit": UNITS.get(n, ""), "meaning": MEANING.get(n, "")} for n in predictor.inputs],
        "outputs": [{"name": n, "unit": UNITS.get(n, ""), "meaning": OUTPUT_MEANING[kind].format(name=n)} for n in outputs],
        "controller_step": {"dt_s": dt, "nominal_step": step},
        "normalisation": {"z_mean": h.z_mean.tolist(), "z_scale": h.z_scale.tolist(), "y_mean": h.y_mean.tolist(),
                          "y_scale": h.y_scale.tolist()},
        "hyperparameters": {
            "length_scale_normalised": np.exp(h.log_ls).tolist(),
            "length_scale_physical": (np.exp(h.log_ls) * h.z_scale[None, :]).tolist(),
            "signal_variance_normalised": np.exp(h.log_sf2).tolist(),
            "noise_variance_normalised": np.exp(h.log_sn2).tolist(),
            "var_scale": np.asarray(predictor.var_scale, float).tolist()},
        "formulas": {
            "normalise": "zn = (z - z_mean) / z_scale; Zn = (Z - z_mean) / z_scale",
            "kernel": ("k_i = signal_variance_o * exp(-0.5 * sum_j ((zn_j - Zn_ij) / length_scale_oj)^2)" if h.kernel == "se"
                       else "r_i = sqrt(sum_j ((zn_j - Zn_ij) / length_scale_oj)^2); k_i = signal_variance_o * (1 + sqrt(3) r_i) * exp(-sqrt(3) r_i)"),
            "mean": "mean_o = y_mean_o + y_scale_o * sum_i k_i * alpha[i, o]",
            "variance_latent": "v = solve_lower(cholesky[group[o]], k); var_o = var_scale_o * y_scale_o^2 * (signal_variance_o - v.v)",
            "variance_measurement": "var_o + var_scale_o * y_scale_o^2 * noise_variance_o",
        },
        "vehicle": None if vehicle is None else {"name": vehicle.name, "config_hash": vehicle.digest(), "toml": vehicle.to_toml()},
        "provenance": provenance or {},
    }
    write_text_atomic(card_path, json.dumps(card, indent=1))
    return card


def _outputs(predictor) -> list[str]:
    from gprace.gp.features import DYN_OUTPUTS

    return list(DYN_OUTPUTS.get(predictor.kind, [f"y{i}" for i in range(predictor.gp.n_outputs_)]))


class PortableGP:
    """The reference evaluator of a portable GP file, numpy and h5py only (module docstring)."""

    def __init__(self, arrays: dict, kernel: str, inputs: list[str]) -> None:
        self.a, self.kernel, self.inputs = arrays, kernel, inputs
        self.Zn = (arrays["Z"] - arrays["z_mean"]) / arrays["z_scale"]

    @classmethod
    def load(cls, path) -> "PortableGP":
        import h5py

        with h5py.File(path, "r") as f:
            arrays = {k: np.asarray(f[k]) for k in f.keys()}
            kernel, inputs = str(f.attrs["kernel"]), json.loads(f.attrs["inputs"])
        return cls(arrays, kernel, inputs)

    def _k(self, zn: np.ndarray, o: int) -> np.ndarray:
        ls = self.a["length_scale"][o]
        d = zn[:, None, :] / ls - self.Zn[None, :, :] / ls
        r2 = np.sum(d * d, axis=-1)
        sf2 = self.a["signal_variance"][o]
        if self.kernel == "se":
            return sf2 * np.exp(-0.5 * r2)
        r = np.sqrt(3.0 * r2)
        return sf2 * (1.0 + r) * np.exp(-r)

    def predict(self, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(mean, latent variance, variance of a new measurement)``, each (m, p), calibrated."""
        a = self.a
        zn = (np.atleast_2d(np.asarray(Z, float)) - a["z_mean"]) / a["z_scale"]
        p = len(a["y_mean"])
        mean, var = np.empty((len(zn), p)), np.empty((len(zn), p))
        for o in range(p):
            K = self._k(zn, o)
            mean[:, o] = a["y_mean"][o] + a["y_scale"][o] * (K @ a["alpha"][:, o])
            L = a["cholesky"][a["group"][o]]
            V = np.linalg.solve(L, K.T)  # L is lower triangular: forward substitution
            var[:, o] = np.maximum(a["signal_variance"][o] - np.sum(V * V, axis=0), 0.0)
        ys2, sc = a["y_scale"] ** 2, a["var_scale"]
        latent = var * ys2 * sc
        return mean, latent, latent + a["noise_variance"] * ys2 * sc
