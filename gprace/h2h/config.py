"""Head-to-head settings: one frozen object per car controller plus the race set-up.

Numbers follow the simulation of Zhu et al. 2022 as collected in docs/reference.md#head-to-head (1:10 BARC cars,
dt 0.1 s, N = 10). Where that set-up is silent, the choices are documented on the fields.
"""

from __future__ import annotations

from pydantic import Field, NonNegativeFloat, field_validator

from gprace.config import Frozen


class MPCConfig(Frozen):
    """Weights and limits of one car's NMPC (ego or opponent)."""

    q_contour: NonNegativeFloat = Field(50.0, description="weight of e_y^2 (contouring to the centre line)")
    q_progress: NonNegativeFloat = Field(200.0, description="reward per metre of progress s_N - s_0")
    r_input: tuple[float, float] = Field((2.0, 2.0), description="weights of delta^2 and a_x^2")
    r_rate: tuple[float, float] = Field((20.0, 20.0), description="weights of the input changes")
    speed_max: float = Field(1.6, gt=0, description="hard speed limit [m/s]")
    speed_soft: float = Field(1.4, gt=0, description="soft speed limit [m/s] (quadratic slack)")
    accel: tuple[float, float] = Field((-1.0, 0.55), description="a_x bounds [m/s^2]")
    steering_max: float = Field(0.435, gt=0, description="|delta| bound [rad]")
    q_block: NonNegativeFloat = Field(0.0, description="blocking weight Q_block / (1 + ds)^2 (opponent only)")
    border_margin: NonNegativeFloat = Field(0.13, description="distance of the car's centre from a border [m] at small "
                                 "heading errors; beyond about 0.29 rad the NLP keeps the footprint's lateral "
                                 "extent plus 1 cm (gprace.h2h.nmpc.border_margin)")
    slack_linear: NonNegativeFloat = Field(2000.0, description="linear penalty of the collision slack")
    slack_quadratic: NonNegativeFloat = Field(2e4, description="quadratic penalty of the collision slack")
    border_linear: NonNegativeFloat = Field(1e5, description="linear penalty of the track-border slack")
    border_quadratic: NonNegativeFloat = Field(1e7, description="quadratic penalty of the track-border slack")
    speed_slack: NonNegativeFloat = Field(200.0, description="quadratic penalty of the soft speed excess")
    substeps: int = Field(2, ge=1, description="RK4 sub-steps of the prediction model (dt/2 is stable "
                          "above 0.4 m/s; below, the model blends into a kinematic one)")
    max_iter: int = Field(60, ge=5, description="IPOPT iteration limit")
    compiled: bool = Field(True, description="NLP functions as compiled C, built once per machine and cached "
                           "(gprace.backends.compiled); false: CasADi's interpreter, 2 to 3 times slower")


def ego_mpc() -> MPCConfig:
    return MPCConfig()


def opponent_mpc() -> MPCConfig:
    """Contouring 75, progress 30 (lower than the ego's 200), input 5 / 25, speed 1.3 (soft 1.0),
    a_x in [-1, 0.45], blocking weight 500 (docs/reference.md#head-to-head, decision: a positive weight)."""
    return MPCConfig(
        q_contour=75.0, q_progress=30.0, r_input=(5.0, 5.0), r_rate=(25.0, 25.0), speed_max=1.3,
        speed_soft=1.0, accel=(-1.0, 0.45), q_block=500.0,
    )


class H2HConfig(Frozen):
    """Race set-up shared by collection, exploration and evaluation."""

    dt: float = Field(0.1, gt=0, description="control period [s]")
    horizon: int = Field(10, ge=2, description="NMPC horizon N")
    pred_steps: int = Field(9, ge=1, description="steps of the opponent prediction (N - 1)")
    plant_substeps: int = Field(10, ge=1, description="RK4 sub-steps of the simulated cars")
    samples: int = Field(50, ge=1, description="GP rollout samples")
    car_length: float = Field(0.26, gt=0)
    car_width: float = Field(0.173, gt=0)
    mpc_length: float = Field(0.36, gt=0, description="car length seen by the collision constraint")
    mpc_width: float = Field(0.2, gt=0)
    disk_radius: float = Field(0.111, gt=0, description="radius of the 4 disks covering the ego")
    std_factor: NonNegativeFloat = Field(1.0, description="ellipse inflation per predicted std [m/m]")
    after_overtake: NonNegativeFloat = Field(1.5, description="seconds simulated after the overtake")
    max_time: float = Field(40.0, gt=0, description="safety stop [s]")
    end_margin: NonNegativeFloat = Field(0.3, description="a run ends when a car is this close to the track end [m]")
    q_explore: tuple[float, float, float] = Field((20.0, 60.0, 5.0), description="J_expl weights on s, e_y, v_x")
    stalemate_steps: int = Field(8, ge=1, description="steps with little change of the relative configuration")
    stalemate_tol: NonNegativeFloat = Field(0.02, description="change threshold of (gap s, gap e_y) per step")
    hold_steps: int = Field(5, ge=1, description="steps a target is held after a stalemate")
    sensor_std: tuple[float, float, float, float, float, float] = Field(
        (0.0,) * 6, description="measurement noise std of each car's state [v_x, v_y, yaw_rate, e_psi, e_y, s] "
        "seen by both controllers and the predictor (per step, white; 0: the true state)")
    process_std: tuple[float, float, float, float, float, float] = Field(
        (0.0,) * 6, description="process noise std added to each car's state after every plant step, same order")
    ego: MPCConfig = Field(default_factory=ego_mpc)
    opponent: MPCConfig = Field(default_factory=opponent_mpc)

    @field_validator("sensor_std", "process_std")
    @classmethod
    def _non_negative(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        if not all(x >= 0 for x in v):  # also rejects NaN
            raise ValueError(f"noise standard deviations must be >= 0, got {list(v)}")
        return v
