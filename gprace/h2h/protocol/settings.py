"""Settings and constants of the head-to-head protocol (:mod:`gprace.h2h.protocol`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

from pydantic import Field, model_validator

from gprace.config import CommandSettings
from gprace.errors import InputError
from gprace.h2h.config import opponent_mpc
from gprace.h2h.predictors import FEATURES, OUTPUTS

SEED_EVAL, SEED_COLLECT, SEED_EXPLORE, SEED_CALIB = 0, 100_000, 200_000, 300_000
# Noise of 1:10 cars, std per state [v_x m/s, v_y m/s, yaw_rate rad/s, e_psi rad, e_y m, s m]
# (sources and reasoning: docs/decisions.md). Sensor: what an estimator fusing indoor
# positioning (cm-level) or motion capture (mm-level) with IMU and encoders gives a 1:10 car,
# white per 0.1 s step. Process: unmodelled forces (surface, tyre, actuator) as a random change of
# the velocities per 0.1 s step; positions follow through the dynamics.
SENSOR_STD = (0.01, 0.01, 0.02, 0.005, 0.005, 0.005)
PROCESS_STD = (0.01, 0.005, 0.02, 0.0, 0.0, 0.0)
BLOCKING_WEIGHT = opponent_mpc().q_block
BASELINE_TRACKS = ("eval", "training")
ERRORS_VERSION = 4  # 2: s errors and raw spreads; 3: one variance per start time; 4: sample_paths (step-0 rounding)
RACED = ("baseline", "explore")
# Backend settings of the opponent GPs (measured on the 5000-point baseline data, docs/decisions.md):
# one kernel for the five outputs (normalised) predicts as well as five kernels at a fifth of the
# rollout cost; the sparse fit starts from the exact optimum on 800 points, polishes it for 50
# iterations and keeps a noise floor (nearly noiseless data made the VFE fit degenerate); its five
# outputs share one kernel too (rollout 3.6 times faster, docs/decisions.md).
GP_SETTINGS: dict[str, dict[str, Any]] = {
    "exact": {"shared_kernel": True},
    "sparse": {"min_noise": 1e-3, "jitter": 1e-6, "max_iter": 50, "init_points": 800, "shared_kernel": True},
}
OFFLINE = ("baseline", "explore", "select", "cv")
CHAIN_STRIDE = 1_000_000  # seeds of chain s: the seeds of chain 0 plus s * CHAIN_STRIDE
VALIDATION_POINTS = 1000
QUALITY_VERSION = 2  # models fitted before the quality reports are refitted (and checked)


class Settings(CommandSettings):
    """The protocol of ``gprace eval head2head`` (defaults: the paper's comparison, docs/reference.md#head-to-head)."""

    OPTIONS: ClassVar[dict[str, str]] = {"backend": "--gp-backend", "raced": "--predictors"}

    tracks: int = Field(100, ge=1, description="evaluation tracks (one race per predictor on each)")
    runs: int = Field(500, ge=1, description="collection races of the baseline's data")
    init_runs: int = Field(20, ge=1, description="collection races of the exploration's first GP")
    explore_minutes: float = Field(10.0, gt=0, description="simulated minutes of active exploration")
    episode_seconds: float = Field(60.0, gt=0, description="length of one exploration episode [s]")
    explore_width: float | None = Field(None, description="width of the exploration loop [m]; None: the racing "
                                        "width (``width``)")
    alpha: float = Field(0.9, ge=0, le=1, description="exploration weight of the exploring ego")
    dict_size: int = Field(600, ge=2, description="points of the exploration's GP dictionary")
    points_per_run: int = Field(10, ge=1, description="training points drawn from each collection race")
    stretches: int = Field(5, ge=1, description="random stretches of an evaluation track")
    width: float = Field(0.75, description="track width [m]")
    raced: tuple[str, ...] = Field(RACED, description="predictors whose egos race the evaluation tracks")
    offline: tuple[str, ...] = Field(OFFLINE, description="predictors whose open-loop errors are measured")
    backend: str = Field("auto", description="GP backend: exact | sparse | auto (sparse above exact_max points)")
    exact_max: int = Field(1500, ge=1, description="most points the exact GP takes with backend auto")
    inducing: int = Field(200, ge=1, description="inducing points of the sparse GP")
    optimize: bool = Field(True, description="fit the GP hyperparameters (False: the defaults)")
    samples: int = Field(50, ge=1, description="samples of the GP opponent rollout")
    max_time: float = Field(60.0, gt=0, description="longest race [s]")
    # conditions of the comparison (issue 17)
    sensor_noise: float = Field(1.0, ge=0, allow_inf_nan=False, description="scale of SENSOR_STD (0: noiseless)")
    process_noise: float = Field(1.0, ge=0, allow_inf_nan=False, description="scale of PROCESS_STD (0: noiseless)")
    baseline_tracks: str = Field("training", description="where the baseline's races run: " + " | ".join(BASELINE_TRACKS))
    blocking_weight: float = Field(BLOCKING_WEIGHT, ge=0, allow_inf_nan=False, description="the opponent's Q_block")
    calib_runs: int = Field(20, ge=1, description="races of each calibration pass")
    calib_passes: int = Field(3, ge=1, description="at most this many driven calibration passes (:func:`calibrate`)")
    config: dict = Field(default_factory=dict, description="H2HConfig entries of the races")
    # execution (not part of any result)
    workers: int = Field(1, ge=1, description="parallel workers")
    executor: str = Field("local", description="local | dask")
    scheduler: str | None = Field(None, description="address of a Dask scheduler")
    resume: bool = Field(False, description="reuse the records already written")
    seeds: tuple[int, ...] = Field((0,), description="chains of the whole protocol (``--seeds``)")
    seed: int = Field(0, description="the chain being run (set per chain by :func:`head2head`)")

    @model_validator(mode="after")
    def _check(self) -> Settings:
        if not self.seeds or min(self.seeds) < 0 or len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"--seeds: a list of distinct seeds >= 0, got {list(self.seeds)}")
        if self.init_runs > self.runs:
            raise ValueError(f"--init-runs ({self.init_runs}) cannot exceed --runs ({self.runs})")
        if self.explore_width is not None:
            from gprace.h2h.geometry import loop_track

            try:
                loop_track(float(self.explore_width))  # the loop's own validity check, before any work
            except InputError as exc:
                raise ValueError(f"--explore-width: {exc}") from None
        from gprace.h2h.config import H2HConfig

        car = 2.0 * H2HConfig().ego.border_margin
        if not self.width > car:
            raise ValueError(f"--width must exceed {car:g} m (the car's footprint kept inside the borders), got {self.width}")
        if self.baseline_tracks not in BASELINE_TRACKS:
            raise ValueError(f"--baseline-tracks must be one of {', '.join(BASELINE_TRACKS)}, got {self.baseline_tracks!r}")
        if self.backend != "auto":
            from gprace.backends import gps

            gps.get(self.backend)  # an unknown name lists the registered ones
        from gprace.gp.selection import dictionary_bytes
        from gprace.resources import check_size

        check_size(f"--dict-size {self.dict_size}", self.dict_size,
                   lambda m: dictionary_bytes(m, len(OUTPUTS), len(FEATURES)), " points")
        # the records of a batch are held together (the table, the datasets): RACE_NUMBERS per step and car
        cfg = H2HConfig()
        race = 8.0 * RACE_NUMBERS * 2 * (self.max_time / cfg.dt + 1)
        for option, n, per, unit in (("--tracks", self.tracks, race * max(len(self.raced), 1), " tracks"),
                                     ("--runs", self.runs, race, " races")):
            check_size(f"{option} {n} with --max-time {self.max_time:g}", n, lambda k, per=per: k * per, unit)
        check_size(f"--samples {self.samples}", self.samples,
                   lambda k: 8.0 * RACE_NUMBERS * k * cfg.horizon * max(self.workers, 1), " samples")
        known = set(OFFLINE) | {"init", "oracle"}
        for p in (*self.raced, *self.offline):
            if p not in known:
                from gprace.errors import UnknownBackendError

                raise UnknownBackendError(f"unknown predictor {p!r}; available: {', '.join(sorted(known))}")
        return self

    def race_config(self) -> dict:
        """The races' :class:`H2HConfig` entries; a condition at its noiseless / default value adds
        nothing (the tasks of such runs keep their hashes)."""
        cfg = dict(self.config, max_time=self.max_time, samples=self.samples)
        if self.sensor_noise > 0:
            cfg["sensor_std"] = [self.sensor_noise * v for v in SENSOR_STD]
        if self.process_noise > 0:
            cfg["process_std"] = [self.process_noise * v for v in PROCESS_STD]
        if self.blocking_weight != BLOCKING_WEIGHT:
            cfg["opponent"] = opponent_mpc().model_copy(update={"q_block": float(self.blocking_weight)}).model_dump(mode="json")
        return cfg

    def conditions(self) -> dict:
        """The conditions of the comparison as the table prints them."""
        return {"sensor_std": [self.sensor_noise * v for v in SENSOR_STD],
                "process_std": [self.process_noise * v for v in PROCESS_STD],
                "baseline_tracks": self.baseline_tracks, "blocking_weight": self.blocking_weight,
                "explore_minutes": self.explore_minutes}


RACE_NUMBERS = 40
"""Numbers kept per race step and car (states, measurements, inputs, predictions, the GP's
training pairs), for the size checks of :class:`Settings`."""


def H2H_K(st: Settings) -> int:
    from gprace.h2h.config import H2HConfig

    return H2HConfig(**st.race_config()).pred_steps


def chain_dir(out: Path, seed: int) -> Path:
    """Folder of one chain: ``out`` itself for seed 0 (the single-seed layout), else ``out/seed_<s>``."""
    return out if seed == 0 else out / f"seed_{seed}"


def parse_seeds(text: str | int) -> tuple[int, ...]:
    """``--seeds``: a count N (seeds 0..N-1) or a comma-separated list of seeds (``"0,4,7"``, ``"5,"``)."""
    t = str(text).strip()
    try:
        if "," not in t:
            n = int(t)
            if n < 1:
                raise InputError(f"--seeds must be a count >= 1 or a list of seeds, got {text!r}")
            return tuple(range(n))
        seeds = tuple(int(x) for x in t.split(",") if x.strip())
    except ValueError:
        raise InputError(f"--seeds must be a count or a comma-separated list of integers, got {text!r}") from None
    if not seeds or min(seeds) < 0 or len(set(seeds)) != len(seeds):
        raise InputError(f"--seeds: a list of distinct seeds >= 0, got {text!r}")
    return seeds
