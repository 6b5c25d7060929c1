"""An INDEPENDENT recording source for the diagnose recovery benchmark (issue 14).

Written apart from gprace's plant, driver and track code (nothing below imports
``gprace.model``, ``gprace.plants``, ``gprace.tracks`` or ``gprace.diagnose.synth``):

- **track generator**: closed polar curves ``r(theta) = R0 (1 + sum_k a_k cos(k theta + phi_k))``
  scaled to a target length, curvature from the analytic derivatives, resampled on arc length;
- **car**: its own parameter set (a GT car, not the Audi) and its own Frenet single-track
  integrator (RK4, 10 ms steps, scalar code) with its own Pacejka-like lateral tire fit per axle
  ``F_y = mu F_z sin(C atan(B alpha))``; the concealed effects are coded here from their physical
  description (a rear-axle *traction* friction ellipse, a cosine-tapered bank/grade window,
  bank, grade and friction varying along the whole lap as a sum of cosine harmonics of the lap
  position, a steering actuator lag ...), not through the catalogue classes;
- **driver**: harder than gprace's: a speed profile at 90-97 % of the friction limit, full drive
  on corner exits, braking at 0.8 g, lateral weaving with a random wavelength, coloured command
  noise, and (on request) a provoked spin: a steering jab mid-corner; after the spin the car
  brakes, the logger drops out for 2.5 s and the car rejoins on the centre line;
- **sensors**: white plus coloured (AR(1), 0.3 s) noise on every channel, time stamps with
  1.5 ms jitter; ``s`` wrapped per lap or, on request, running on over the laps (a logger that
  never resets it), with no lap length in the meta then.

The nominal vehicle (gprace TOML schema, :func:`vehicle_config`) describes this car exactly, except
the concealed effect.
"""

from __future__ import annotations

import math

import numpy as np

G0 = 9.81

CAR = dict(name="indep_gt", mass=1380.0, yaw_inertia=1950.0, l_f=1.18, l_r=1.42, width=1.9, length=4.5,
           cog_height=0.48, mu=1.25, drag_coefficient=0.36, rolling_resistance=0.013, v_min=1.0,
           tire=dict(b_front=11.5, c_front=1.45, b_rear=13.0, c_rear=1.5),
           limits=dict(steering_max=0.45, steering_rate_max=1.2, accel_min=-11.0, accel_max=5.5, speed_max=72.0))


def vehicle_config():
    """The car above in gprace's vehicle schema (the nominal model of this source)."""
    from gprace.config import VehicleConfig

    return VehicleConfig(**CAR)


# ------------------------------------------------------------------------------------------
# track


class Loop:
    """A closed track as a curvature table over arc length (what the recordings need)."""

    def __init__(self, seed: int, length: float = 2000.0, width: float = 6.0):
        rng = np.random.default_rng(seed + 101)
        for _ in range(200):  # draw until the tightest corner is drivable
            th = np.linspace(0.0, 2 * np.pi, 6001)[:-1]
            ks = np.arange(2, 8)
            a = rng.uniform(0.0, 1.0, len(ks)) * 0.22 / ks ** 0.9
            ph = rng.uniform(0, 2 * np.pi, len(ks))
            arg = np.outer(th, ks) + ph
            r = 1.0 + np.cos(arg) @ a
            r1 = -(ks * np.sin(arg)) @ a
            r2 = -(ks ** 2 * np.cos(arg)) @ a
            kap = (r * r + 2 * r1 * r1 - r * r2) / (r * r + r1 * r1) ** 1.5
            ds = np.sqrt(r * r + r1 * r1) * (th[1] - th[0])
            L1 = float(ds.sum())
            scale = length / L1
            kap = kap / scale
            if np.min(1.0 / np.maximum(np.abs(kap), 1e-9)) > 22.0 and np.max(kap) > 1 / 150:
                break
        s = np.concatenate([[0.0], np.cumsum(ds * scale)[:-1]])
        self.length = float(np.sum(ds) * scale)
        grid = np.linspace(0.0, self.length, int(self.length / 1.0), endpoint=False)
        self.s_tab = grid
        self.k_tab = np.interp(grid, s, kap, period=self.length)
        self.width = width
        self.name = f"loop{seed}"

    def kappa(self, s):
        return np.interp(np.mod(s, self.length), self.s_tab, self.k_tab, period=self.length)


# ------------------------------------------------------------------------------------------
# car with concealed effects


def _taper(s: float, a: float, b: float, L: float, edge: float = 3.0) -> float:
    """1 inside [a, b] along the lap (cosine edges of ``edge`` m), 0 outside."""
    x = (s - a) % L
    w = (b - a)
    if x > w + edge:
        return 0.0
    if x < edge:
        return 0.5 - 0.5 * math.cos(math.pi * x / edge)
    if x > w:
        return 0.5 + 0.5 * math.cos(math.pi * (x - w) / edge)
    return 1.0


def harmonics(amplitudes, phases, s: float, L: float) -> float:
    """A smooth periodic profile over the lap: ``sum_k a_k cos(2 pi k s / L + phi_k)``, k = 1, 2, ..."""
    x = 2.0 * math.pi * s / L
    return sum(a * math.cos((k + 1) * x + p) for k, (a, p) in enumerate(zip(amplitudes, phases)))


class Car:
    """Frenet single track. State [vx, vy, r, epsi, ey, s, delta_actual, ax_actual]."""

    def __init__(self, hidden: dict[str, dict], track: Loop):
        self.h = hidden
        self.tr = track
        c = CAR
        self.m, self.iz, self.lf, self.lr, self.hc = c["mass"], c["yaw_inertia"], c["l_f"], c["l_r"], c["cog_height"]
        self.mu, self.cxw, self.crr = c["mu"], c["drag_coefficient"], c["rolling_resistance"]
        t = c["tire"]
        self.bf, self.cf, self.br, self.cr = t["b_front"], t["c_front"], t["b_rear"], t["c_rear"]
        self.vmin = c["v_min"]
        H = hidden
        if "yaw_inertia" in H:
            self.iz *= H["yaw_inertia"]["factor"]
        if "cornering_stiffness" in H:
            self.bf *= H["cornering_stiffness"].get("front", 1.0)
            self.br *= H["cornering_stiffness"].get("rear", 1.0)
        self.cxw += H.get("aero_drag", {}).get("c_d", 0.0)
        self.crr += H.get("rolling_resistance", {}).get("c_rr", 0.0)
        self.tau_d = H.get("steering_lag", {}).get("tau", 0.0)
        self.tau_a = H.get("drivetrain_lag", {}).get("tau", 0.0)
        self.d_off = H.get("steering_offset", {}).get("offset", 0.0)

    def deriv(self, x, dcmd, acmd):
        vx, vy, r, ep, ey, s, dl, al = x
        H, m, L = self.h, self.m, self.lf + self.lr
        delta = (dl if self.tau_d > 0 else dcmd) + self.d_off
        ax = al if self.tau_a > 0 else acmd
        fzf, fzr = m * G0 * self.lr / L, m * G0 * self.lf / L
        if "downforce" in H:
            f = H["downforce"]["c_l"] * vx * vx
            bal = H["downforce"].get("balance", 0.45)
            fzf, fzr = fzf + bal * f, fzr + (1 - bal) * f
        if "load_transfer" in H:
            d = m * ax * H["load_transfer"]["cog_height"] / L
            fzf, fzr = fzf - d, fzr + d
        muf = mur = self.mu
        if "tire_friction" in H:
            muf *= H["tire_friction"].get("front", 1.0)
            mur *= H["tire_friction"].get("rear", 1.0)
        if "tire_load_sensitivity" in H:
            k, f0 = H["tire_load_sensitivity"]["k"], 0.5 * m * G0
            muf *= 1 - k * (fzf - f0) / f0
            mur *= 1 - k * (fzr - f0) / f0
        if "friction_patch" in H:
            p = H["friction_patch"]
            w = 1 + (p["factor"] - 1) * _taper(s, p["s_start"], p["s_end"], self.tr.length)
            muf, mur = muf * w, mur * w
        if "friction_profile" in H:  # grip varying along the lap around 1
            p = H["friction_profile"]
            w = 1 + harmonics(p["amplitudes"], p["phases"], s, self.tr.length)
            muf, mur = muf * w, mur * w
        u = max(vx, self.vmin)
        af = delta - math.atan((vy + self.lf * r) / u)
        ar = -math.atan((vy - self.lr * r) / u)
        fyf = muf * fzf * math.sin(self.cf * math.atan(self.bf * af))
        fyr = mur * fzr * math.sin(self.cr * math.atan(self.br * ar))
        if "combined_slip" in H and ax > 0:  # rear-axle traction only: a friction ellipse under drive
            q = m * ax / (mur * fzr)
            fyr *= math.sqrt(max(1 - H["combined_slip"]["k"] * q * q, 0.05))
        grade = bank = 0.0
        if "road_grade" in H:
            p = H["road_grade"]
            grade = p["angle"] * _taper(s, p["s_start"], p["s_end"], self.tr.length)
        if "road_bank" in H:
            p = H["road_bank"]
            bank = p["angle"] * _taper(s, p["s_start"], p["s_end"], self.tr.length)
        if "road_grade_profile" in H:  # a closed lap: the harmonics climb as much as they fall
            p = H["road_grade_profile"]
            grade = harmonics(p["amplitudes"], p["phases"], s, self.tr.length)
        if "road_bank_profile" in H:
            p = H["road_bank_profile"]
            bank = p.get("mean", 0.0) + harmonics(p["amplitudes"], p["phases"], s, self.tr.length)
        k = float(self.tr.kappa(s))
        cd, sd = math.cos(delta), math.sin(delta)
        dvx = ax - (fyf * sd + self.crr * m * G0 + self.cxw * vx * vx) / m - G0 * math.sin(grade) + r * vy
        dvy = (fyf * cd + fyr - m * G0 * math.sin(bank)) / m - r * vx
        dr = (self.lf * fyf * cd - self.lr * fyr) / self.iz
        sdot = (vx * math.cos(ep) - vy * math.sin(ep)) / (1 - k * ey)
        ddl = (dcmd - dl) / self.tau_d if self.tau_d > 0 else 0.0
        dal = (acmd - al) / self.tau_a if self.tau_a > 0 else 0.0
        return np.array([dvx, dvy, dr, r - k * sdot, vx * math.sin(ep) + vy * math.cos(ep), sdot, ddl, dal])

    def step(self, x, dcmd, acmd, dt, n=5):
        h = dt / n
        for _ in range(n):  # a simulation in time (sequential by nature)
            k1 = self.deriv(x, dcmd, acmd)
            k2 = self.deriv(x + 0.5 * h * k1, dcmd, acmd)
            k3 = self.deriv(x + 0.5 * h * k2, dcmd, acmd)
            k4 = self.deriv(x + h * k3, dcmd, acmd)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return x


# ------------------------------------------------------------------------------------------
# driver


class HardDriver:
    def __init__(self, track: Loop, rng, dt: float, grip_use: float):
        c = CAR
        self.tr, self.rng, self.dt = track, rng, dt
        self.L = c["l_f"] + c["l_r"]
        lim = c["limits"]
        self.dmax, self.rate, self.amin, self.amax = lim["steering_max"], lim["steering_rate_max"], lim["accel_min"], lim["accel_max"]
        self.lam = rng.uniform(110.0, 260.0)
        self.amp = rng.uniform(0.25, 0.45) * (track.width - 1.5)
        s = track.s_tab
        # the weave adds curvature amp (2 pi / lambda)^2 on top of the track's
        k = np.abs(track.k_tab) + self.amp * (2 * np.pi / self.lam) ** 2
        v = np.minimum(np.sqrt(grip_use * c["mu"] * G0 / k), 65.0)
        m, L = c["mass"], self.L
        cf = c["mu"] * m * G0 * c["l_r"] / L * c["tire"]["b_front"] * c["tire"]["c_front"]
        cr = c["mu"] * m * G0 * c["l_f"] / L * c["tire"]["b_rear"] * c["tire"]["c_rear"]
        self.kus = m * (c["l_r"] / cf - c["l_f"] / cr) / L
        # forward (drive) and backward (brake) passes over the table, twice around
        h = s[1] - s[0]
        vv = np.concatenate([v, v, v])
        for i in range(1, len(vv)):  # one-off over ~6000 track points
            vv[i] = min(vv[i], math.sqrt(vv[i - 1] ** 2 + 2 * h * 0.9 * self.amax))
        for i in range(len(vv) - 2, -1, -1):
            vv[i] = min(vv[i], math.sqrt(vv[i + 1] ** 2 + 2 * h * 0.8 * G0 * c["mu"] * 0.8))
        self.v_ref = vv[len(v): 2 * len(v)]
        self.nd = self.na = 0.0
        self.dprev = 0.0
        self.jab = 0.0

    def __call__(self, y):
        vx, vy, r, ep, ey, s = y[:6]
        v = max(vx, 3.0)
        w = 2 * math.pi / self.lam
        look = 0.6 * v
        ey_ref = self.amp * math.sin(w * (s + look))
        k_ff = float(self.tr.kappa(s + 0.3 * v))
        beta = math.atan2(vy, v)
        # path curvature demand from a look-ahead point (own law: not gprace's driver)
        err = (ey - ey_ref) + look * math.sin(ep + beta)
        kap_cmd = k_ff - 2.0 * err / (look * look)
        delta = math.atan(self.L * kap_cmd) + self.kus * v * v * kap_cmd - 1.5 * self.L / v * (r - v * kap_cmd)
        a = math.exp(-self.dt / 0.35)
        self.nd = a * self.nd + math.sqrt(1 - a * a) * self.rng.standard_normal()
        self.na = a * self.na + math.sqrt(1 - a * a) * self.rng.standard_normal()
        delta += 0.9 * self.L * self.nd / max(v, 12.0) ** 2 + self.jab
        dm = self.rate * self.dt
        delta = min(max(delta, self.dprev - dm), self.dprev + dm)
        delta = min(max(delta, -self.dmax), self.dmax)
        self.dprev = delta
        vr = float(np.interp((s + 0.5 * v) % self.tr.length, self.tr.s_tab, self.v_ref, period=self.tr.length))
        ax = 2.5 * (vr - vx) + 0.7 * self.na
        # full drive on corner exits (trimmed by feel on the friction circle), hard braking
        circle = math.sqrt(max(1.0 - (v * r / (CAR["mu"] * G0)) ** 2, 0.15))
        ax = min(max(ax, self.amin * 0.8 * circle), self.amax * circle)
        return delta, ax


# ------------------------------------------------------------------------------------------
# recording


NOISE_WHITE = np.array([0.04, 0.025, 0.004, 0.003, 0.03, 0.08])
NOISE_COLOURED = np.array([0.03, 0.015, 0.002, 0.002, 0.03, 0.1])
CORR_S = 0.3


def record(hidden: dict[str, dict], seed: int, duration_s: float = 180.0, spin: bool = False,
           dt: float = 0.05, track_length: float = 2000.0, s_runs_on: bool = False):
    """One recording as a dict of columns plus meta (lap length); with ``s_runs_on`` the logged
    ``s`` is not wrapped per lap and the meta does not give the lap length."""
    rng = np.random.default_rng(seed)
    tr = Loop(seed, track_length)
    car = Car(hidden, tr)
    grip = float(rng.uniform(0.85, 0.93))
    drv = HardDriver(tr, rng, dt, grip)
    n = int(duration_s / dt)
    s0 = float(rng.uniform(0, tr.length))
    v0 = float(np.interp(s0, tr.s_tab, drv.v_ref))
    x = np.array([v0, 0.0, v0 * float(tr.kappa(s0)), 0.0, 0.0, s0, 0.0, 0.0])
    t_spin = rng.uniform(0.35, 0.65) * duration_s if spin else np.inf
    rows, U, T = [], [], []
    t, k, spun, jab_left = 0.0, 0, False, 0
    while k < n:
        y = x[:6].copy()
        d, a = drv(y)
        if not spun and t >= t_spin and abs(float(tr.kappa(y[5]))) > 1 / 300 and jab_left == 0:
            jab_left = int(0.6 / dt)
            drv.jab = 0.2 * math.copysign(1.0, float(tr.kappa(y[5])))
            spun = True
        if jab_left:
            jab_left -= 1
            if jab_left == 0:
                drv.jab = 0.0
        rows.append(y), U.append((d, a)), T.append(t)
        x = car.step(x, d, a, dt)
        t += dt
        k += 1
        beta = math.atan2(x[1], max(abs(x[0]), 0.5))
        if abs(beta) > 0.6 or abs(x[3]) > 1.2 or abs(x[4]) > tr.width + 4:
            # spun: 1.5 s more of braking recorded, then a logger gap and a restart
            for _ in range(int(1.5 / dt)):
                y = x[:6].copy()
                rows.append(y), U.append((0.0, -6.0)), T.append(t)
                x = car.step(x, 0.0, -6.0 if x[0] > 1.0 else 0.0, dt)
                x[0] = max(x[0], 0.0)
                t += dt
                k += 1
            t += 2.5
            s_new = x[5] + 30.0
            v_new = 8.0
            x = np.array([v_new, 0.0, v_new * float(tr.kappa(s_new)), 0.0, 0.0, s_new, 0.0, 0.0])
            drv.dprev = math.atan((car.lf + car.lr) * float(tr.kappa(s_new)))
            drv.jab, jab_left = 0.0, 0
    Y = np.array(rows)[:n]
    U = np.array(U)[:n]
    T = np.array(T)[:n]
    m = len(T)
    if "gyro_bias" in hidden:
        Y[:, 2] = Y[:, 2] + hidden["gyro_bias"]["bias"]
    # sensors: white + AR(1) coloured noise (vectorised filter), jittered time stamps
    from scipy.signal import lfilter

    a = math.exp(-dt / CORR_S)
    col = lfilter([math.sqrt(1 - a * a)], [1, -a], rng.standard_normal((m, 6)), axis=0)
    Y = Y + NOISE_WHITE * rng.standard_normal((m, 6)) + NOISE_COLOURED * col
    T = T + rng.normal(0.0, 0.0015, m)
    s = Y[:, 5] if s_runs_on else np.mod(Y[:, 5], tr.length)
    data = {"t": T, "s": s, "e_y": Y[:, 4], "e_psi": Y[:, 3], "v_x": Y[:, 0], "v_y": Y[:, 1], "yaw_rate": Y[:, 2],
            "delta": U[:, 0], "a_x": U[:, 1], "kappa": tr.kappa(s)}
    if s_runs_on:
        return data, {"dt": dt, "track": tr.name}
    return data, {"dt": dt, "track_length": tr.length, "track": tr.name}
