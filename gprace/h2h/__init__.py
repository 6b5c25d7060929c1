"""Head-to-head racing against a blocking opponent (paper section on the GP opponent predictor).

Public surface::

    from gprace.h2h import H2HConfig, NMPC, run_race, make_predictor, Settings, head2head
    from gprace.h2h import RaceAttrs, ErrorAttrs, read_record, H2HTable, read_table

:mod:`~gprace.h2h.config` (settings of both cars and the race), :mod:`~gprace.h2h.nmpc` (the
NMPC of either car), :mod:`~gprace.h2h.predictors` (opponent predictors: GP, constant velocity,
oracle), :mod:`~gprace.h2h.fastroll` (the compiled GP rollout), :mod:`~gprace.h2h.race` (one race),
:mod:`~gprace.h2h.explore` (active exploration of interactions), :mod:`~gprace.h2h.protocol` (the
paper's comparison, resumable), :mod:`~gprace.h2h.records` (the schemas of its per-race records),
:mod:`~gprace.h2h.table` (the schema of its table), :mod:`~gprace.h2h.spread` (bootstrap, seeds, calibration, verdicts),
:mod:`~gprace.h2h.geometry` (tracks, border hits, collisions) and :mod:`gprace.cli.h2h` (CLI).
"""

from gprace._lazy import lazy_face

__all__, __getattr__ = lazy_face(__name__, {
    "config": "H2HConfig MPCConfig", "nmpc": "NMPC StageData Solution", "race": "run_race",
    "predictors": "make_predictor Prediction Context GPPredictor load_opponent_gp", "explore": "Explorer",
    "protocol": "Settings head2head", "geometry": "make_track",
    "records": "RaceAttrs ErrorAttrs Record read_record write_record", "table": "H2HTable read_table"})
