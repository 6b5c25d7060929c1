"""Unit checks of a recording by robust statistics and by consistency between its channels.

A speed column in km/h is off by 3.6 everywhere, not in one slide; a yaw rate in deg/s is 57.3
times the heading change that ``e_psi``, ``kappa`` and ``s`` imply. So the checks rest on
quantiles and medians of the whole file and on the kinematic relations of the Frenet frame, and a
spin (a few seconds of large ``v_y`` and ``yaw_rate``) passes: it is cut out by
:mod:`gprace.io.envelope`, not read as a units error. Called by
:func:`gprace.io.runs.check_columns`.
"""

from __future__ import annotations

import numpy as np

from gprace.errors import InputError

_UNITS = ((3.6, "km/h instead of m/s"), (1 / 3.6, "m/s where km/h was expected"),
          (57.3, "degrees instead of rad"), (1 / 57.3, "rad where degrees were expected"))
_LAG_S = 0.5  # consistency checks compare channels over this interval (sensor noise averages out)


def unit_hint(ratio: float) -> str:
    for f, text in _UNITS:
        if abs(np.log(ratio / f)) < np.log(1.25):
            return f" ({text}?)"
    return ""


def check_units(data: dict[str, np.ndarray], source: str, plausible: dict) -> None:
    """Units by robust statistics of the whole file and by consistency between channels.

    1. robust magnitudes (a quantile of |x|, ``plausible``: column -> (quantile, limit, hint));
    2. the speed along the path from ``s`` and ``t`` against the one the Frenet kinematics give
       from ``v_x, v_y, e_psi, e_y, kappa`` (``s' = (v_x cos e_psi - v_y sin e_psi)/(1 - kappa e_y)``);
    3. ``yaw_rate`` against the heading change ``d(e_psi)/dt + kappa ds/dt``, as a two-factor fit
       ``yaw_rate = a d(e_psi)/dt + b kappa ds/dt`` (a = b = 1 in SI; both 57.3 for deg/s; a = 1/57.3
       for e_psi in degrees).
    Quantiles over the samples inside the envelope (:mod:`gprace.io.envelope`), medians and fits over
    the whole file, so a spin or a slide does not move them; a check runs
    only when the file has enough motion to decide. The error names the column and the probable unit.

    A magnitude is a fallback: a column whose relation to the path (2, 3, ``v_y`` against the
    lateral motion) confirms SI units is not refused for being large. A lost lap's log can be a
    few seconds of a car fishtailing into a spin (slides of 15 degrees the envelope keeps, as it
    keeps any slide short of a spin; measured at Norisring: 90th percentile of |v_y| 9.1 m/s over
    the kept samples of a 6 s log); its v_y agrees with the lateral motion, a v_y in km/h does not.
    """
    from gprace.io.envelope import envelope

    n = len(data["t"])
    keep, _ = envelope(data)  # magnitudes over the samples a model can describe (not a long spin)
    # a recording that is mostly outside the envelope (a lap that spun early) has no typical
    # magnitude to judge: the consistency checks below still see its units
    large = []
    for c, (q, lim, hint) in (plausible.items() if keep.sum() >= max(0.2 * n, 2) else ()):
        m = float(np.quantile(np.abs(data[c][keep]), q))
        if m > lim:
            large.append((c, f"{source}: column {c!r} has a typical magnitude of {m:.3g} ({100 * q:.0f}th percentile of "
                             f"|{c}|), implausible in SI units (limit {lim}); check units ({hint})"))
    errors, confirmed = _consistency(data, source)
    for c, msg in large:
        if c not in confirmed:
            raise InputError(msg)
    if errors:
        raise InputError(errors[0])


CONFIRM = (0.8, 1.25)
"""A consistency factor in this range (with a fit that explains the data) confirms SI units."""


def _confirms(factor: float, r2: float = 1.0) -> bool:
    return bool(r2 > 0.5 and CONFIRM[0] < factor < CONFIRM[1])


def _consistency(data: dict[str, np.ndarray], source: str) -> tuple[list[str], set[str]]:
    """The consistency checks of :func:`check_units`: the errors they find, in the order they are
    checked, and the columns whose relation to the path confirms SI units."""
    errors: list[str] = []
    confirmed: set[str] = set()
    n = len(data["t"])
    t, s = data["t"], data["s"]
    dt = float(np.median(np.diff(t)))
    k = int(np.clip(round(_LAG_S / max(dt, 1e-9)), 1, max(n // 4, 1)))
    if n < 4 * k + 4:
        return errors, confirmed
    ds, dT = s[k:] - s[:-k], t[k:] - t[:-k]

    def mean_over(x):  # mean of x over each interval [i, i+k]
        c = np.concatenate([[0.0], np.cumsum(x)])
        return (c[k + 1:] - c[:-k - 1]) / (k + 1)

    vx, vy, epsi, ey, kap = (data[c] for c in ("v_x", "v_y", "e_psi", "e_y", "kappa"))
    denom = 1.0 - kap * ey

    def sdot_of(epsi):  # the speed along the path the Frenet kinematics give
        return mean_over((vx * np.cos(epsi) - vy * np.sin(epsi)) / np.where(np.abs(denom) > 0.1, denom, 1.0))

    sdot_model = sdot_of(epsi)
    sdot = ds / dT
    gap_free = dT < 1.5 * k * dt
    # steps where s skips ahead of the distance driven (the nearest point jumping across a hairpin
    # tighter than the car's offset, a lap wrap): windows holding one are left out
    step = np.diff(s)
    speed = np.hypot(vx, vy)
    skip = np.abs(step) > 2.5 * 0.5 * (speed[1:] + speed[:-1]) * np.diff(t) + 1e-3
    n_skip = np.concatenate([[0], np.cumsum(skip)])
    clean = (n_skip[k:] - n_skip[:-k]) == 0
    moving = gap_free & clean & (ds > 0) & (sdot_model > 2.0) & (sdot < 3.0 * np.quantile(sdot, 0.99) + 1.0)
    # lap wraps make ds negative and are dropped by ds > 0
    if moving.sum() < 20:
        return errors, confirmed
    ratio = float(np.median(sdot_model[moving] / np.maximum(sdot[moving], 1e-9)))
    # e_psi in degrees spoils cos(e_psi), not v_x: blame it when e_psi / 57.3 makes them agree
    in_rad = float(np.median(sdot_of(epsi / 57.3)[moving] / np.maximum(sdot[moving], 1e-9)))
    if not (0.67 < ratio < 1.5) and 0.67 < in_rad < 1.5:
        errors.append(f"{source}: column 'e_psi' in degrees instead of rad? (with e_psi / 57.3 the speed along the path "
                      f"from 'v_x' agrees with 's' and 't'; as it is, {ratio:.3g} times it)")
    if not (0.67 < ratio < 1.5):
        errors.append(f"{source}: column 'v_x' is {ratio:.3g} times the speed along the path from 's' and 't' "
                      f"(median over the file){unit_hint(ratio) or ' (check units of v_x, s and t)'}")
    elif _confirms(ratio):
        confirmed.add("v_x")
    # yaw rate vs heading change
    depsi = (epsi[k:] - epsi[:-k]) / dT
    rate = mean_over(data["yaw_rate"])[moving]
    # the reference heading change over each window: the integral of kappa along s (a
    # product of window means would be wrong where kappa changes within a window: a 1:10
    # car passes a hairpin in 0.5 s)
    turn = np.concatenate([[0.0], np.cumsum(0.5 * (kap[1:] + kap[:-1]) * np.where(skip, 0.0, step))])
    X = np.column_stack([depsi[moving], ((turn[k:] - turn[:-k]) / dT)[moving]])
    errors += _lateral_checks(data, source, k, dT, moving, mean_over, rate, confirmed)
    if np.std(X[:, 1]) > 0.02 and np.std(rate) > 0.02:
        coef, *_ = np.linalg.lstsq(X, rate, rcond=None)
        a, b = (float(x) for x in coef)
        fit = X @ coef
        r2 = 1.0 - np.sum((rate - fit) ** 2) / max(np.sum((rate - rate.mean()) ** 2), 1e-300)
        if r2 > 0.5:  # the channels do carry a heading relation: check its factors
            if not (0.67 < b < 1.5):
                errors.append(f"{source}: column 'yaw_rate' is {b:.3g} times the heading change from 'kappa' and "
                              f"'s'{unit_hint(b) or ' (check units of yaw_rate and kappa)'}")
            elif _confirms(b):
                confirmed.add("yaw_rate")
            if abs(a) > 1e-9 and not (0.5 < a < 2.0) and unit_hint(a):
                errors.append(f"{source}: column 'e_psi' changes {1 / a:.3g} times faster than 'yaw_rate' allows"
                              f"{unit_hint(1 / a)}")
    return errors, confirmed


def _fit1(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Slope of ``y = c x`` (through 0) and its R^2."""
    c = float(np.dot(x, y) / max(np.dot(x, x), 1e-300))
    r2 = 1.0 - float(np.sum((y - c * x) ** 2) / max(np.sum((y - y.mean()) ** 2), 1e-300))
    return c, r2


def _lateral_checks(data, source, k, dT, moving, mean_over, rate, confirmed: set[str]) -> list[str]:
    """``v_y`` against the lateral motion ``d(e_y)/dt - v_x sin(e_psi)`` (slope 1 in SI, 1/3.6 for
    km/h), and ``delta`` against the yaw rate it produces: ``yaw_rate ~ v_x delta / l`` with an
    effective wheelbase ``l`` of 0.1 to 12 m for any car with linear tires below 30 m/s; degrees
    make it 57 times longer. Returns the errors; adds ``v_y`` to ``confirmed`` when its slope is 1."""
    errors = []
    vx, vy, epsi, ey, delta = (data[c] for c in ("v_x", "v_y", "e_psi", "e_y", "delta"))
    dey = (ey[k:] - ey[:-k]) / dT
    lat = (dey - mean_over(vx * np.sin(epsi)))[moving]
    vyc = mean_over(vy * np.cos(epsi))[moving]
    if np.std(vyc) > 0.05 and np.std(lat) > 0.05:  # both must move for a slope to mean anything
        c, r2 = _fit1(vyc, lat)
        if r2 > 0.5 and not (0.5 < c < 2.0):
            errors.append(f"{source}: column 'v_y' is {1 / c:.3g} times the lateral speed from 'e_y' and 'e_psi'"
                          f"{unit_hint(1 / c) or ' (check units of v_y and e_y)'}")
        elif _confirms(c, r2):
            confirmed.add("v_y")
    # only where the tires are linear and the speed moderate: there the effective wheelbase is
    # l + K v^2 < 12 m for any car in rad (understeer gradient K < 0.01 rad per m/s^2); at the
    # limit or at 60 m/s an understeering race car shows 20 to 40 m (Budapest: 37 m, in rad)
    vxm = mean_over(vx)[moving]
    lin = (np.abs(vxm * rate) < 5.0) & (vxm < 30.0)
    x = mean_over(vx * delta)[moving][lin]
    rate = rate[lin]
    if lin.sum() >= 20 and np.std(x) > 0.05 and np.std(rate) > 0.02:
        c, r2 = _fit1(x, rate)
        if r2 > 0.5 and 0.0 < c < 0.05:
            errors.append(f"{source}: column 'delta' turns the car like a {1 / c:.0f} m wheelbase "
                          f"(yaw_rate / (v_x delta)); check units (degrees instead of rad?)")
    return errors
