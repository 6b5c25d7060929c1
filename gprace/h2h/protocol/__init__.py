"""The paper's head-to-head protocol: collect, train, explore, select, race, tabulate.

One module per concern: :mod:`.settings` (the protocol's settings and constants), :mod:`.batches`
(runs through the executor, records reused by task hash), :mod:`.data` (tasks and datasets:
collection, exploration, validation), :mod:`.training` (the GP fits), :mod:`.evaluation` (races of
the predictors, offline errors, calibration of the spread) and :mod:`.summary` (the table over
seeds). The tasks themselves are typed (:mod:`gprace.h2h.tasks`).

Layout of ``--out DIR`` (every file an HDF5 artifact, written atomically)::

    collect/runs/run_<i>.h5       one record per collection race (oracle predictor), kind h2h_run
    collect/dataset.h5            (Z, Y) of all collection runs, a GP dataset (gprace.gp.dataset,
                                  feature map opponent; before issue 40 kind h2h_dataset)
    collect/validation.h5         held-out steps of the collection runs (in no dataset): fit quality
    init/runs/run_<i>.h5          the exploration's start runs (``init_runs`` oracle races on
                                  evaluation-style tracks) when the baseline collects on the
                                  training tracks (the default, ``--baseline-tracks training``)
    init/dataset.h5               the exploration's start: those runs, or the first ``init_runs``
                                  collection runs with ``--baseline-tracks eval``
    explore/runs/run_<i>.h5       exploration episodes on the closed loop (alpha = 0.9)
    explore/dataset.h5            init data + exploration data
    models/{baseline,init,explore,select}.h5   GP models (kind gp_model)
    eval/<predictor>/run_<i>.h5   the races of every predictor on the same scenarios
    errors/<predictor>/run_<i>.h5 offline e_y errors of every offline predictor on those races
                                  (and ``spread_<predictor>``: |s error|, raw std of s and e_y)
    calib/runs/run_<i>.h5         held-out races (oracle predictor, evaluation-style tracks, own
                                  seeds): the first calibration of every predictor's spread
    calib/errors/run_<i>.h5       offline errors and raw spreads of every predictor on them
    calib/<raced>/runs, errors    the second pass: held-out races driven by the raced predictors
    calib/pass<k>/<raced>/...     further passes until the calibration settles (``calib_passes``)
    calib/passes.json             per driven pass: the calibration it drove with, the one fitted, settled
    calib/calibration_oracle.json the first calibration (the second pass drives with it)
    calib/calibration.json        per predictor, step and output: scale and floor of the spread
    table.json                    the comparison table (all seeds)
    seed_<s>/...                  the same layout for chain seed s > 0 (``--seeds``)

Every batch of runs goes through :func:`gprace.executor.run_batch`. Each run record stores a hash
of its task; with ``resume`` a record whose hash matches is kept and only missing or failed runs
are rerun. A run that raises is recorded (``ok = False`` and its error) and skipped by the table.
Records are written and read only through their schemas (:mod:`gprace.h2h.records`: a race, the
offline errors of a race); a reused record of an older layout is migrated.
Datasets and models are reused when present and built from the same inputs (their ``config_hash``).

Every GP fit goes through :func:`gprace.gp.quality.checked_fit`: its quality report (noise,
hyperparameters at bounds, held-out error on ``collect/validation.h5`` against an exact GP on a
subsample) is stored in the model's ``quality`` attribute and printed; a degenerate fit is retried
and otherwise refused (FitError, exit 2), so it is never raced.

Seeds (``--seeds``): chain s repeats collection, training and exploration with every seed shifted
by ``s * CHAIN_STRIDE`` (seed 0 is the single-seed protocol, same runs, same folder) and races the
same evaluation scenarios; :mod:`gprace.h2h.spread` gives every figure's spread over seeds next to
its bootstrap interval over tracks and judges the paper's claims against both.

Conditions (each in the table's settings; a changed condition changes the task hashes of exactly
the runs it affects, so ``--resume`` reruns those): ``sensor_noise`` and ``process_noise`` scale
:data:`SENSOR_STD` and :data:`PROCESS_STD` (both cars, every race; 0 = noiseless, the task then
carries no noise entry); ``baseline_tracks`` (``training``, the default: the short ``curve``
and ``chicane`` tracks of Zhu et al. 2022, alternating, where the paper's baseline data come
from; ``eval``: the random evaluation-style tracks; only the baseline collection runs change, the
exploration's start runs are evaluation-style in both, in ``init/runs`` with ``training``);
``blocking_weight`` (the opponent's, every race; the default adds nothing to the tasks);
``explore_minutes``.

Calibrated spread: before the evaluation, held-out races give every predictor's errors and raw
spreads per step (offline rollouts as for the table's errors; ``calib_runs`` oracle races, then
``calib_runs`` races per pass driven in turn by the raced predictors until the calibration settles,
:func:`calibrate`);
:func:`gprace.h2h.spread.fit_calibration` turns them into a per-step scale (GP predictors) or
floor (constant velocity), carried by the evaluation tasks and applied in the predictors, so the
ellipses are inflated by a spread that covers the real error; the table gives the coverage of the
2-sigma band on the evaluation races, raw and calibrated, per predictor.

Decisions (the paper is silent): each collection run contributes ``points_per_run`` (10) evenly
spaced steps, which gives the paper's "about 5000 points" from 500 runs (all points of the
exploration episodes go to the diverse selection); the exploration GP's "20 runs" are the first 20 runs of the
baseline collection (same mechanism, no extra cost); exploration time is split into episodes of
``episode_seconds`` on the loop, each restarted from a random grid (runs in parallel), with the
loop at the racing width (``explore_width``; measured: exploring the 1.5 m loop for 0.75 m races
gave a 9-step error of 0.064 m against 0.026 m at 0.75 m, docs/decisions.md); the
"selection only" GP is a diverse selection from the baseline data with as many points as the
exploration GP's dictionary; GPs with more than ``exact_max`` points use the ``sparse`` backend.
"""

from gprace.h2h.protocol.batches import race_with_data, run_tasks
from gprace.h2h.protocol.data import (calib_tasks, collect, collect_tasks, dataset_from_records, eval_tasks, explore,
                                      read_dataset)
from gprace.h2h.protocol.evaluation import (calibrate, coverage, offline_error_columns, offline_error_data,
                                            offline_errors, race_predictors)
from gprace.h2h.protocol.settings import (BASELINE_TRACKS, BLOCKING_WEIGHT, CHAIN_STRIDE, ERRORS_VERSION,
                                          GP_SETTINGS, OFFLINE, PROCESS_STD, RACED, SEED_CALIB, SEED_COLLECT,
                                          SEED_EVAL, SEED_EXPLORE, SENSOR_STD, VALIDATION_POINTS, Settings,
                                          chain_dir, parse_seeds)
from gprace.h2h.protocol.summary import head2head, run_chain, table
from gprace.h2h.protocol.training import fit_report, models, report_fits, train
from gprace.h2h.tasks import RACE_VERSION, task_hash

__all__ = [
    "BASELINE_TRACKS", "BLOCKING_WEIGHT", "CHAIN_STRIDE", "ERRORS_VERSION", "GP_SETTINGS", "OFFLINE",
    "PROCESS_STD", "RACED", "RACE_VERSION", "SEED_CALIB", "SEED_COLLECT", "SEED_EVAL", "SEED_EXPLORE", "SENSOR_STD",
    "VALIDATION_POINTS", "Settings", "calib_tasks", "calibrate", "chain_dir", "collect", "collect_tasks", "coverage",
    "dataset_from_records", "eval_tasks", "explore", "fit_report", "head2head", "models", "offline_error_columns",
    "offline_error_data", "offline_errors", "parse_seeds", "race_predictors", "race_with_data", "read_dataset",
    "report_fits", "run_chain", "run_tasks", "table", "task_hash", "train",
]
