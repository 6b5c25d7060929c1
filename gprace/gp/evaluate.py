"""GP error metrics on a recording (``gprace evaluate gp``)."""

from __future__ import annotations

import numpy as np

Z95 = 1.959963984540054


def gp_metrics(gp, Z: np.ndarray, Y: np.ndarray, output_names: list[str]) -> dict:
    """Per output: RMSE and MAE of the GP mean, the share of measured errors inside the 95% interval
    of a new measurement (latent variance plus noise: calibration), and the RMSE of the nominal
    model alone (the raw errors, i.e. a zero prediction)."""
    mean, var = gp.predict(Z)
    resid = Y - mean
    band = Z95 * np.sqrt(var + gp.noise_)
    out = {}
    for i, name in enumerate(output_names):
        r = resid[:, i]
        rmse = float(np.sqrt(np.mean(r**2)))
        nominal = float(np.sqrt(np.mean(Y[:, i] ** 2)))
        out[name] = {
            "rmse": rmse,
            "mae": float(np.mean(np.abs(r))),
            "inside_95": float(np.mean(np.abs(r) <= band[:, i])),
            "nominal_rmse": nominal,
            "rmse_reduction": float(1.0 - rmse / nominal) if nominal > 0 else 0.0,
            "mean_std": float(np.mean(np.sqrt(var[:, i]))),
        }
    return out
