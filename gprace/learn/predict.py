"""The prediction a lap is held to, and how a recorded lap compares with it.

**The GP's band along the lap** (:func:`lateral_band`): at every node of the plan, the spread of
the car's lateral position that the tracking MPC itself assumes: the tracking GP's predictive
variance of the one-step errors of ``v_y`` and ``yaw_rate`` (calibrated, latent plus noise)
propagated through the nominal model's linearised step along the plan over the MPC's horizon
(``Sigma_{j+1} = A_j Sigma_j A_j^T + diag(0, var_vy, var_r, 0, 0, 0)``, the recursion of its
chance constraints), and its two-sided 95 % quantile ``1.96 sigma_ey``. Where the GP is unsure,
the band is wide. A driven lap *leaves the band* where its distance from the planned line exceeds
it: there the car did something the learned model did not foresee.

**Where the plan uses most of the learned grip** (:func:`grip_use`): the use of the friction
ellipse the plan was made in (the limits learned from the measured envelope),
``sqrt((a_x / a_lim)^2 + (v_x r / a_lat)^2)``, and the stretches where it is highest.

**Prediction errors** (:func:`prediction_errors`): one- and ``H``-step predictions of a recording's
``[v_x, v_y, yaw_rate]`` from its own inputs, by the nominal model and by the nominal model plus
the tracking GP's mean, started at every usable sample (vectorised over the starts), and the share
of the one-step errors inside the GP's 95 % band.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gprace.errors import InputError

Z95 = 1.959963984540054  # two-sided 95 % quantile of a unit Gaussian


# ------------------------------------------------------------------------------------------------
# the band and the grip


def plan_grid(plan, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The plan sampled every ``dt`` of its own time over one lap: times (m,), states (m, 6), inputs (m, 2)."""
    t = np.arange(0.0, plan.lap_time, dt)
    X, U = plan.at_time(t)
    return t, X, U


def lateral_band(plan, track, model, gp, dt: float, horizon: int, level: float = 0.95) -> dict:
    """Half-width (n,) of the ``level`` band of ``e_y`` at the plan's nodes (module docstring) and
    the GP's standard deviations of the one-step errors there."""
    from scipy.stats import norm

    t, X, U = plan_grid(plan, dt)
    m = len(t)
    A = np.empty((m, 6, 6))
    for i in range(m):  # one small CasADi call per sample of a lap (offline, once per iteration)
        A[i] = model.jacobians(X[i], U[i], float(track.kappa(X[i, 5])), dt)[0][:6, :6]
    _, var = gp.predictive(_inputs(gp, X, U))
    # covariance after `horizon` steps from every start, all starts at once (periodic in the lap)
    S = np.zeros((m, 6, 6))
    idx = np.arange(m)
    for j in range(horizon):
        k = (idx + j) % m
        S = np.einsum("nij,njk,nlk->nil", A[k], S, A[k])
        S[:, 1, 1] += var[k, 0]
        S[:, 2, 2] += var[k, 1]
    sig_end = np.sqrt(np.maximum(S[:, 4, 4], 0.0))
    # the band at a sample is the spread predicted *for* it, i.e. from the start `horizon` steps before
    band_t = norm.ppf(0.5 + level / 2) * np.roll(sig_end, horizon)
    node_t = plan.t
    return {"band": np.interp(node_t, t, band_t, period=plan.lap_time),
            "sigma_vy": np.interp(node_t, t, np.sqrt(var[:, 0]), period=plan.lap_time),
            "sigma_r": np.interp(node_t, t, np.sqrt(var[:, 1]), period=plan.lap_time)}


def _inputs(gp, X, U):
    from gprace.gp.features import dyn_inputs

    return dyn_inputs(X, U, gp.inputs)


def grip_use(plan, limits) -> np.ndarray:
    """Use (n,) of the plan's friction ellipse at each node (1 = on it)."""
    a_lat, a_drive, a_brake = (float(v) for v in limits)
    a_lon = np.where(plan.a_x >= 0, plan.a_x / a_drive, -plan.a_x / a_brake)
    return np.sqrt(a_lon**2 + (plan.v_x * plan.yaw_rate / a_lat) ** 2)


def stretches(mask: np.ndarray, closed: bool = True) -> list[tuple[int, int]]:
    """``[(first, last), ...]`` of the runs of True in ``mask`` (on a closed lap a run may wrap)."""
    m = np.asarray(mask, bool)
    if not m.any():
        return []
    if m.all():
        return [(0, len(m) - 1)]
    from gprace.io.envelope import true_runs

    a, b = true_runs(m)
    runs = list(zip(a.tolist(), b.tolist()))
    if closed and len(runs) > 1 and runs[0][0] == 0 and runs[-1][1] == len(m) - 1:
        runs = [(runs[-1][0], runs[0][1])] + runs[1:-1]
    return runs


def grip_places(plan, use: np.ndarray, limits, top: int = 3, on: float = 0.97) -> list[dict]:
    """The ``top`` corners where the plan uses the most of its learned grip: peaks of the lateral
    share ``|v_x r| / a_lat`` where the plan is on its ellipse (``use >= on``), each with the
    stretch around it where the lateral share stays above 80 % of its peak, ranked by that peak.
    (A minimum-time plan rides its ellipse nearly everywhere, braking and driving included; the
    corners are where the learned lateral grip decides the lap.)"""
    lat = np.abs(plan.v_x * plan.yaw_rate) / float(limits[0])
    n = len(lat)
    peak = (lat >= np.roll(lat, 1)) & (lat >= np.roll(lat, -1)) & (use >= on * float(use.max()))
    out, taken = [], np.zeros(n, bool)
    for k in np.flatnonzero(peak)[np.argsort(-lat[peak])]:
        if taken[k]:
            continue
        a = b = k
        while lat[(a - 1) % n] >= 0.8 * lat[k] and (a - 1) % n != k:
            a -= 1
        while lat[(b + 1) % n] >= 0.8 * lat[k] and (b + 1) % n != k:
            b += 1
        taken[np.arange(a, b + 1) % n] = True
        out.append({"s_start": float(plan.s[a % n]), "s_end": float(plan.s[b % n]), "s_peak": float(plan.s[k]),
                    "use": float(use[k]), "lateral": float(lat[k]), "v_x": float(plan.v_x[k]),
                    "a_lat": float(plan.v_x[k] * plan.yaw_rate[k]), "a_x": float(plan.a_x[k])})
        if len(out) == top:
            break
    return out


@dataclass
class Prediction:
    """What an iteration predicts for the next lap on its plan (``prediction.h5``)."""

    s: np.ndarray  # centre-line arc length of the plan's nodes [m]
    x: np.ndarray
    y: np.ndarray  # the planned line in the global frame [m]
    e_y: np.ndarray  # planned lateral offset [m]
    speed: np.ndarray  # planned speed over ground [m/s]
    band: np.ndarray  # half-width of the 95 % band of e_y [m]
    sigma_vy: np.ndarray
    sigma_r: np.ndarray  # the tracking GP's predictive std of the one-step errors at the nodes
    use: np.ndarray  # use of the learned friction ellipse
    lap_time: float
    track_length: float

    ARRAYS = ("s", "x", "y", "e_y", "speed", "band", "sigma_vy", "sigma_r", "use")

    def write(self, path) -> None:
        from gprace.io.artifacts import Artifact, write_artifact

        write_artifact(path, Artifact("prediction", {k: np.asarray(getattr(self, k), float) for k in self.ARRAYS},
                                      {"lap_time": float(self.lap_time), "track_length": float(self.track_length)}))

    @classmethod
    def read(cls, path) -> "Prediction":
        from gprace.io.artifacts import read_artifact

        a = read_artifact(path, "prediction")
        return cls(**{k: np.asarray(a.arrays[k], float) for k in cls.ARRAYS}, lap_time=float(a.attrs["lap_time"]),
                   track_length=float(a.attrs["track_length"]))


def predict(plan, track, model, gp, dt: float, horizon: int, limits) -> Prediction:
    """The :class:`Prediction` of a plan driven with the tracking GP ``gp``."""
    b = lateral_band(plan, track, model, gp, dt, horizon)
    x, y = track.to_global(plan.s, plan.e_y)
    return Prediction(s=plan.s, x=x, y=y, e_y=plan.e_y, speed=np.hypot(plan.v_x, plan.v_y), band=b["band"],
                      sigma_vy=b["sigma_vy"], sigma_r=b["sigma_r"], use=grip_use(plan, limits),
                      lap_time=float(plan.lap_time), track_length=float(track.length))


def plan_along(plan, track, model=None, gp=None, dt: float = 0.05, horizon: int = 15, limits=None) -> tuple[dict, np.ndarray | None]:
    """What an MCAP shows along a plan (:mod:`gprace.io.foxglove`): per node ``s, x, y, speed``;
    with a tracking GP the band and the GP's standard deviations (:func:`lateral_band`, the band is
    also returned); with friction limits the ellipse's use. ``(along, band or None)``."""
    x, y = track.to_global(plan.s, plan.e_y)
    along = {"s": plan.s, "x": x, "y": y, "speed": np.hypot(plan.v_x, plan.v_y)}
    band = None
    if gp is not None:
        b = lateral_band(plan, track, model, gp, dt, horizon)
        band = b["band"]
        along.update(b)
    if limits is not None and len(limits) == 3:
        along["use"] = grip_use(plan, limits)
    return along, band


# ------------------------------------------------------------------------------------------------
# a recorded lap against the prediction


def lap_bounds(run, length: float) -> list[tuple[int, int]]:
    """``[(first, end), ...]`` sample indices of the laps recorded whole: between two crossings of
    the line (the lap counter steps), or from the first sample when the recording starts on the
    line (within 1 % of a lap, as gprace's own runs do); a "lap" that covers less than 90 % of the
    track (a start just behind the line, counted again just after it) is none."""
    lap = np.asarray(run["lap"]) if "lap" in run.data else np.zeros(run.n)
    idx = list(np.flatnonzero(np.diff(lap) > 0) + 1)
    s0 = float(np.mod(run["s"][0], length))
    if min(s0, length - s0) < 0.01 * length and (not idx or idx[0] > 0):
        idx = [0] + idx
    pos = np.mod(np.asarray(run["s"]), length) + lap * length  # continuous through the laps
    return [(a, b) for a, b in zip(idx[:-1], idx[1:]) if pos[b] - pos[a] >= 0.9 * length]


def full_laps(run, length: float) -> list[float]:
    """Times [s] of the laps recorded whole (:func:`lap_bounds`)."""
    t = run["t"]
    return [float(t[b] - t[a]) for a, b in lap_bounds(run, length)]




def compare_laps(pred: Prediction, run, keep: np.ndarray | None = None, min_excess: float = 0.0) -> dict:
    """Each full lap of ``run`` (a Frenet run on the prediction's track) against the prediction:
    lap time, speed along s (difference, RMS and the largest), and the stretches where the car
    left the band (``|e_y - e_y_plan| > band``), with how far and where."""
    L = pred.track_length
    s = np.mod(run["s"], L)
    keep = np.ones(run.n, bool) if keep is None else keep
    sp = np.append(pred.s, L)

    def along(a):
        return np.interp(s, sp, np.append(a, a[0]))

    dev = np.asarray(run["e_y"]) - along(pred.e_y)
    band = along(pred.band)
    dv = np.hypot(run["v_x"], run["v_y"]) - along(pred.speed)
    bounds = lap_bounds(run, L)
    times = [float(run["t"][b] - run["t"][a]) for a, b in bounds]
    laps = []
    for n_lap, (a, b) in enumerate(bounds):
        sl = np.arange(a, b)
        ok = keep[sl]
        out = (np.abs(dev[sl]) > band[sl] + min_excess) & ok
        left = []
        for i, j in stretches(out, closed=False):
            seg = sl[i:j + 1]
            worst = seg[np.argmax(np.abs(dev[seg]) - band[seg])]
            left.append({"s_start": float(s[seg[0]]), "s_end": float(s[seg[-1]]), "t_start": float(run["t"][seg[0]]),
                         "max_excess_m": float(np.abs(dev[worst]) - band[worst]), "at_s": float(s[worst]),
                         "deviation_m": float(dev[worst]), "band_m": float(band[worst])})
        big = sl[np.argmax(np.abs(dv[sl]))]
        laps.append({"lap": n_lap, "time_s": times[n_lap], "time_error_s": times[n_lap] - pred.lap_time,
                     "speed_rms_mps": float(np.sqrt(np.mean(dv[sl][ok] ** 2))) if ok.any() else float("nan"),
                     "speed_mean_mps": float(np.mean(dv[sl][ok])) if ok.any() else float("nan"),
                     "speed_max_mps": float(dv[big]), "speed_max_at_s": float(s[big]),
                     "inside_band": float(np.mean(~out[ok])) if ok.any() else float("nan"), "left_band": left})
    return {"predicted_lap_s": pred.lap_time, "laps": laps,
            "best_lap_s": min(times) if times else float("nan"),
            "left_band": sum(len(x["left_band"]) for x in laps)}


# ------------------------------------------------------------------------------------------------
# one- and multi-step prediction errors


def prediction_errors(model, track, run, gp=None, horizon: int = 15, keep: np.ndarray | None = None) -> dict:
    """RMS errors of the one- and ``horizon``-step predictions of ``[v_x, v_y, yaw_rate]`` from
    the recorded inputs, started at every sample whose window is regular in time and usable,
    for the nominal model and (``gp``) the nominal model plus the tracking GP's mean; and the share
    of the one-step ``[v_y, yaw_rate]`` errors inside the GP's 95 % band."""
    X, U = run.states(), run.inputs()
    t, dt, n = run["t"], run.dt, run.n
    if n <= horizon + 1:
        raise InputError(f"{run.source}: {n} samples; a {horizon}-step prediction needs more")
    keep = np.ones(n, bool) if keep is None else np.asarray(keep, bool)
    regular = np.abs(np.diff(t) - dt) < 1e-6 * max(dt, 1.0)
    ok = np.ones(n - horizon, bool)
    for j in range(horizon):
        ok &= regular[j:n - horizon + j] & keep[j:n - horizon + j]
    ok &= keep[horizon:]
    starts = np.flatnonzero(ok)
    if len(starts) < 10:
        raise InputError(f"{run.source}: fewer than 10 usable windows of {horizon} steps")
    out = {"starts": int(len(starts)), "horizon": horizon, "dt": dt}
    for name, g in (("nominal", None), ("learned", gp)):
        if name == "learned" and g is None:
            continue
        x = X[starts].copy()
        err1 = None
        for j in range(horizon):
            u = U[starts + j]
            xn = model.rk4(x, u, track.kappa, dt)
            if g is not None:
                xn[:, 1:3] += g.at(x, u)[0]
            x = xn
            if j == 0:
                err1 = x[:, :3] - X[starts + 1, :3]
        errH = x[:, :3] - X[starts + horizon, :3]
        out[name] = {"one_step_rms": np.sqrt(np.mean(err1**2, axis=0)).tolist(),
                     f"{horizon}_step_rms": np.sqrt(np.mean(errH**2, axis=0)).tolist()}
    if gp is not None:
        x0, u0 = X[starts], U[starts]
        y = X[starts + 1, 1:3] - model.rk4(x0, u0, track.kappa, dt)[:, 1:3]
        mean, var = gp.predictive(_inputs(gp, x0, u0))
        out["learned"]["one_step_coverage"] = np.mean(np.abs(y - mean) <= Z95 * np.sqrt(var), axis=0).tolist()
    out["states"] = ["v_x", "v_y", "yaw_rate"]
    return out
