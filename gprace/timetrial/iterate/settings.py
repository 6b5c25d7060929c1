"""The settings of ``gprace iterate`` and the check that an experiment can start (before any work)."""

from __future__ import annotations

from typing import ClassVar

from pydantic import Field, model_validator

from gprace.config import CommandSettings
from gprace.errors import InputError


class IterateSettings(CommandSettings):
    """The iterative double-GP time trial (``gprace iterate``; defaults: the paper's schedule)."""

    OPTIONS: ClassVar[dict[str, str]] = {"alphas": "--alpha", "dictionary_size": "--dictionary-size"}

    alphas: tuple[float, ...] = Field((0.857, 0.714, 0.0), description="exploration weight of iteration 1, 2, ...; "
                                      "the last holds for the rest")
    iterations: int = Field(7, ge=1, description="GP iterations after the nominal iteration 0")
    trials: int = Field(3, ge=1, description="independent repetitions")
    selection: str = Field("diverse", description="how the dictionary keeps points: diverse | random")
    plant: str = Field("audi_hidden", description="the plant driven (shipped name or TOML path)")
    track: str = Field("gprace_ring", description="track: shipped name or a TUM CSV/TOML path")
    vehicle: str = Field("audi_tt_cup", description="the nominal model's vehicle")
    dictionary_size: int = Field(1000, ge=10, description="points of each GP's dictionary")
    max_fit_points: int = Field(300, ge=1, description="points the hyperparameter fit uses at most")
    plan_ds: float = Field(6.0, gt=0, description="arc-length step of the planner [m]")
    first_speed_scale: float = Field(0.7, gt=0, le=1, description="speed scale of the first, GP-free plan")
    plan_grip: float = Field(1.0, gt=0, description="cap of the widened ellipse: share of the nominal model's limits")
    widen: float = Field(0.05, ge=0, lt=0.5, description="widening of the measured envelope per clean lap")
    widen_max: float = Field(0.15, ge=0, lt=0.5, description="widening per clean lap that used little of the tires' "
                             "slip (gprace.timetrial.grip.widening)")
    features: str = Field("full", description='GP inputs: "full" or "paper" (gprace.gp.features.DYN_FEATURE_SETS)')
    grip: bool = Field(True, description="rear-slip constraint in the tracking MPC")
    oracle: bool = Field(True, description="plan and drive the oracle lap (frenet plants)")
    solver: str = Field("clarabel", description="QP backend of the tracking MPC")
    beta: float = Field(0.6, description="chance-constraint probability of the tracking MPC")
    laps: float = Field(1.0, gt=0, description="laps per trial and iteration")
    seed: int = Field(0, description="seed of trial 0 (trial t: seed + t)")
    grid_values: int = Field(7, ge=2, description="candidate values per exploration dimension")
    heldout_laps: float = Field(1.0, gt=0, description="laps of the held-out reference run")
    heldout_weave: float = Field(0.7, ge=0, description="weave of the held-out run [m]")
    calib_weave: float = Field(0.4, ge=0, description="weave of the calibration run [m]; 0: leave-one-out "
                               "calibration only")
    shakedown: bool = Field(True, description="iteration 0 is a shakedown that widens its limits from what the car "
                            "shows (False: the curvature plan at first_speed_scale)")
    shakedown_start: float = Field(0.5, gt=0, le=1, description="share of the nominal model's limits the shakedown "
                                   "starts at")
    delay: float | None = Field(None, ge=0, description="total steering and measurement delay the MPC predicts over "
                                "[s]; None: the vehicle's known delays, else estimated in the shakedown")
    envelope: bool = Field(True, description="run-time stability envelope (eases the reference when the car leaves "
                           "the band of its own laps)")
    never_worse: bool = Field(True, description="drive a GP plan only if predicted safe; after a lost or slower lap go "
                              "back to the last good plan and limits")
    slower_tolerance: float = Field(0.005, ge=0, description="an alpha-0 lap slower than the best by more than this "
                                    "share counts as slower")

    @model_validator(mode="after")
    def _check(self) -> IterateSettings:
        if not self.alphas:
            raise ValueError("--alpha: give at least one value")
        bad = [a for a in self.alphas if not 0.0 <= a <= 1.0]
        if bad:
            raise ValueError(f"--alpha: values must be in [0, 1], got {bad[0]}")
        if self.selection not in ("diverse", "random"):
            raise ValueError(f"--selection must be diverse or random, got {self.selection!r}")
        from gprace.backends import solvers
        from gprace.gp.features import dyn_feature_set
        from gprace.mpc.tracking import quantile_factor

        dyn_feature_set(self.features)
        solvers.get(self.solver)  # an unknown name lists the registered ones, before any planning
        quantile_factor(self.beta)
        self._check_dictionary_size()
        if self.delay is not None:
            from gprace.errors import ConfigError
            from gprace.mpc.delay import check
            from gprace.mpc.tracking import MPCSettings

            mpc = MPCSettings()
            try:
                check(self.delay, mpc.N, mpc.dt, "--delay")
            except ConfigError as exc:
                raise ValueError(str(exc)) from None
        return self

    def _check_dictionary_size(self) -> None:
        """Both GPs' dictionaries (selection and exact fit) must fit in memory, before any work."""
        from gprace.gp.features import dyn_feature_set, feature_map
        from gprace.gp.selection import dictionary_bytes
        from gprace.resources import check_size

        p, d = sum(len(feature_map(k).output_names) for k in ("tracking", "planning")), len(dyn_feature_set(self.features))
        check_size(f"--dictionary-size {self.dictionary_size}", self.dictionary_size,
                   lambda m: dictionary_bytes(m, p, d), " points")

    def alpha(self, i: int) -> float:
        """alpha of iteration i >= 1."""
        return float(self.alphas[min(i - 1, len(self.alphas) - 1)])


def _check_start(settings: IterateSettings) -> None:
    """Load track, plant and vehicle, and check the car can start on iteration 0's plan (InputError)."""
    from gprace.model import NominalModel, load_plant, load_vehicle
    from gprace.plan import curvature_plan
    from gprace.timetrial.drive import start_state
    from gprace.tracks import load_track

    track = load_track(settings.track)
    plant = load_plant(settings.plant)
    vehicle = load_vehicle(settings.vehicle)
    model = NominalModel(vehicle)
    if plant.vehicle.name != vehicle.name:
        # a model of another car is a legitimate experiment, and an easy slip (--vehicle is not
        # read from the plant): say so once, before hours of laps
        from gprace.console import console

        console.warn(f"iterate: the nominal vehicle is {vehicle.name!r}, the plant {settings.plant!r} is built "
                     f"on {plant.vehicle.name!r}; pass --vehicle {plant.vehicle.name} unless a model of another car is meant")
    if not track.closed:
        raise InputError(f"--track {settings.track}: an open track; the time trial needs a closed lap")
    if settings.delay is None and vehicle.known_delay is not None:
        from gprace.mpc.delay import check
        from gprace.mpc.tracking import MPCSettings

        mpc = MPCSettings()
        check(vehicle.known_delay, mpc.N, mpc.dt, f"--vehicle {settings.vehicle}: actuator_delay + measurement_delay")
    start_state(curvature_plan(track, model, ds=settings.plan_ds, speed_scale=settings.first_speed_scale), track, model.vehicle)
