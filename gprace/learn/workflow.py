"""``gprace learn RECORDINGS... --track T --vehicle V --out DIR``: one iteration of the paper's loop
from recorded laps.

Stages of an iteration (each writes its artifacts atomically, then a marker under ``.steps/``; a
rerun with the same recordings resumes at the first unfinished stage, a rerun after the last stage
prints the result again):

1. **import**: every recording becomes a Frenet run on the track (raw CSV / MCAP / bag / MDF4
   through :func:`gprace.ingest.importer.import_recording` with the map; gprace runs as they are).
   The track is taken in the direction the car drives it; recordings of another track, or driven
   the other way round, are refused.
2. **select**: the usable samples (the envelope, :func:`gprace.io.envelope.envelope`: no spins,
   standstill, reversing) stream into both GPs' dictionaries, continuing the previous iteration's
   (the paper's diverse selection or the random baseline, as ``iterate``); the hyperparameters are
   fitted once, on the first iteration's data (:mod:`gprace.timetrial.learning`).
3. **retrain**: both GPs' posteriors on their dictionaries; the variance calibrated on the
   leave-one-out errors and, as a split-conformal check across laps, on each lap of this
   iteration's data predicted by the GP fitted without that lap.
4. **plan**: the minimum-time lap with the planning GP, warm-started from the previous plan,
   inside the friction ellipse widened from the envelope the recordings measured
   (:mod:`gprace.timetrial.grip`: a failed lap narrows it, a border hit holds it).
5. **export**: the raceline as TUM and F1TENTH CSV (:mod:`gprace.tracks.raceline`), the tracking
   GP as a portable model (:mod:`gprace.gp.export`); with ``--alpha`` the exploration candidates
   and the reference of Algorithm 1 along the plan.
6. **predict**: the prediction the next lap is held to (:mod:`gprace.learn.predict`).

Folder (``--out DIR``)::

    learn.json                      the car, track and learning settings (another car is refused)
    hyper_tracking.h5 hyper_planning.h5
    iter_<k>/sources.json           the recordings of iteration k (paths, sha256)
    iter_<k>/rec_<j>.h5             imported recordings
    iter_<k>/data_*.h5 gp_*.h5 plan.h5 raceline_tum.csv raceline_f1tenth.csv
    iter_<k>/gp_tracking.portable.h5 gp_tracking.card.json [candidates.h5 explore_reference.csv]
    iter_<k>/prediction.h5 record.json stages.json (the stages' results, for resuming)
    .steps/iter_<k>.<stage>.done
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, ClassVar, NamedTuple

import numpy as np
from pydantic import Field, model_validator

from gprace.config import CommandSettings
from gprace.console import console
from gprace.errors import InputError, SolverError

STAGES = ("import", "select", "retrain", "plan", "export", "predict")
LEARN_VERSION = 1
KINDS = ("tracking", "planning")


class LearnSettings(CommandSettings):
    """One iteration of the double-GP loop from recorded laps (``gprace learn``)."""

    OPTIONS: ClassVar[dict[str, str]] = {"dictionary_size": "--dictionary-size", "map_file": "--map"}

    track: str = Field(description="track: a centre-line CSV, two boundary files, an F1TENTH waypoint file or a shipped name")
    vehicle: str = Field(description="the nominal vehicle (shipped name or TOML path)")
    map_file: str | None = Field(None, description="recording map of raw recordings (default: <name>.map.toml beside each)")
    dt: float = Field(0.05, gt=0, le=1, description="period the recordings are resampled to [s]: the controller's step")
    alpha: float | None = Field(None, ge=0, le=1, description="exploration weight; with it the candidates and the "
                                "reference of Algorithm 1 are written")
    dictionary_size: int = Field(1000, ge=10, description="points of each GP's dictionary")
    features: str = Field("full", description='GP inputs: "full" or "paper"')
    selection: str = Field("diverse", description="how the dictionary keeps points: diverse | random")
    max_fit_points: int = Field(300, ge=20, description="points the hyperparameter fit uses at most")
    plan_ds: float | None = Field(None, gt=0, description="planner node spacing [m] (default: 6 m, at most 1/250 of the lap)")
    widen: float = Field(0.05, ge=0, lt=0.5, description="widening of the measured envelope per clean iteration")
    widen_max: float = Field(0.15, ge=0, lt=0.5, description="widening per clean iteration that used little of the "
                             "tires' slip (gprace.timetrial.grip.widening), as iterate")
    driven: str | None = Field(None, description="the plan or raceline the recordings drove (gprace plan, TUM or "
                               "F1TENTH CSV): the widening starts from its limits and it is the warm start; default "
                               "the previous iteration's plan, at the first the measured envelope (not widened)")
    never_worse: bool = Field(True, description="as iterate: after a lost or slower lap go back to the last good plan's "
                              "limits; a new plan not predicted safe is replaced by the last good one")
    slower_tolerance: float = Field(0.005, ge=0, description="a lap slower than the best by more than this share counts "
                                    "as slower (never_worse)")
    plan_grip: float = Field(1.0, gt=0, description="cap of the ellipse: share of the nominal model's limits")
    grid_values: int = Field(7, ge=2, description="candidate values per exploration dimension")
    seed: int = Field(0, description="seed of the hyperparameter fit and the selection")

    @model_validator(mode="after")
    def _check(self) -> LearnSettings:
        from gprace.gp.features import dyn_feature_set

        dyn_feature_set(self.features)
        if self.selection not in ("diverse", "random"):
            raise ValueError(f"--selection must be diverse or random, got {self.selection!r}")
        return self

    def identity(self) -> dict:
        """What an ``--out`` folder's iterations must share (learning settings; the car and track
        are checked apart)."""
        return {k: getattr(self, k) for k in ("dt", "features", "selection", "dictionary_size", "max_fit_points")}


# ------------------------------------------------------------------------------------------------
# the folder


def write_json(path: Path, obj) -> None:
    from gprace.console import jsonable
    from gprace.io.artifacts import write_text_atomic

    write_text_atomic(path, json.dumps(jsonable(obj), indent=1, allow_nan=False))


def read_json(path: Path) -> dict:
    from gprace.io.records import read_json as _read

    return _read(path, path.name)


class Folder:
    """An ``--out`` folder: identity, iterations, stage markers."""

    def __init__(self, out: Path) -> None:
        self.out = Path(out)
        self.steps = self.out / ".steps"

    def it(self, k: int) -> Path:
        return self.out / f"iter_{k:02d}"

    def iterations(self) -> list[int]:
        return sorted(int(p.name[5:]) for p in self.out.glob("iter_[0-9]*") if (p / "sources.json").exists())

    def done(self, k: int, stage: str) -> bool:
        return (self.steps / f"iter_{k:02d}.{stage}.done").exists()

    def mark(self, k: int, stage: str) -> None:
        from gprace.io.artifacts import write_text_atomic

        self.steps.mkdir(parents=True, exist_ok=True)
        write_text_atomic(self.steps / f"iter_{k:02d}.{stage}.done", time.strftime("%Y-%m-%dT%H:%M:%S"))

    def finished(self, k: int) -> bool:
        return self.done(k, STAGES[-1])

    def record(self, k: int) -> dict:
        return read_json(self.it(k) / "record.json")


def car_identity(vehicle, track, settings: LearnSettings) -> dict:
    from gprace.plan import track_hash

    return {"version": LEARN_VERSION, "vehicle": vehicle.name, "vehicle_hash": vehicle.digest(), "track": track.name,
            "track_hash": track_hash(track), "track_reversed": bool(getattr(track, "is_reversed", False)),
            "track_spec": settings.track, "settings": settings.identity()}


def check_identity(folder: Folder, mine: dict) -> None:
    """InputError when ``--out`` holds iterations of another car, track or learning settings."""
    path = folder.out / "learn.json"
    if not path.exists():
        if folder.out.exists() and any(folder.out.iterdir()) and not folder.iterations():
            marks = [p.name for p in folder.out.iterdir() if p.name in ("settings.json", "summary.json")]
            if marks:
                raise InputError(f"--out {folder.out}: holds a gprace iterate experiment, not learn iterations; use another --out")
        return
    old = read_json(path)
    if old.get("vehicle_hash") != mine["vehicle_hash"]:
        raise InputError(f"--out {folder.out}: holds the iterations of car {old.get('vehicle')!r} (config {old.get('vehicle_hash')}), "
                         f"not of {mine['vehicle']!r} (config {mine['vehicle_hash']}); use another --out")
    if old.get("track_hash") != mine["track_hash"]:
        raise InputError(f"--out {folder.out}: learned on track {old.get('track')!r} ({old.get('track_hash')}), not on "
                         f"{mine['track']!r} ({mine['track_hash']}); use another --out")
    diff = sorted(k for k in mine["settings"] if old.get("settings", {}).get(k) != mine["settings"][k])
    if diff:
        raise InputError(f"--out {folder.out}: learned with other settings ({', '.join(diff)}); use another --out")


# ------------------------------------------------------------------------------------------------
# recordings


def file_sha(path: Path) -> str:
    from gprace.ingest.importer import file_hash

    return file_hash(Path(path))


def choose_iteration(folder: Folder, sources: list[dict]) -> tuple[int, bool]:
    """``(k, new)``: the iteration these recordings belong to (an existing one with the same
    recordings: resumed or already done) or the next one. An unfinished last iteration of other
    recordings is an error (its recordings must be learned first)."""
    mine = sorted(s["sha256"] for s in sources)
    its = folder.iterations()
    for k in its:
        theirs = sorted(s["sha256"] for s in read_json(folder.it(k) / "sources.json")["recordings"])
        if theirs == mine:
            return k, False
    if its and not folder.finished(its[-1]):
        names = ", ".join(s["path"] for s in read_json(folder.it(its[-1]) / "sources.json")["recordings"])
        raise InputError(f"--out {folder.out}: iteration {its[-1]} (from {names}) is unfinished; rerun it with the "
                         "same recordings first")
    return (its[-1] + 1 if its else 1), True


def _is_raw(path: Path) -> bool:
    """A raw recording (imported) rather than a gprace run: anything but an HDF5 run or a CSV with
    Frenet columns (``s``, ``e_y``); the map decides what a raw file's columns mean."""
    from gprace.ingest.readers import recording_format
    from gprace.io.table import peek_names

    if path.suffix.lower() in (".h5", ".hdf5"):
        return False
    if recording_format(path) == "csv":
        return not {"s", "e_y"} <= set(peek_names(path))
    return True


OTHER_TRACK = ("off track", "does not drive along", "never comes within")
"""What the importer says of a recording of another circuit."""


CURVATURE_MISMATCH = 0.2
"""A run is of another track when its curvature along s differs from the track's by more than
this share of the track's typical curvature (90th percentile of |kappa|), in the median."""


def _check_run_track(path: Path, run, track) -> None:
    """A gprace run must be of ``track``: by the track name and lap length it names, and by the
    curvature it recorded (a Frenet CSV names neither)."""
    name = str(run.meta.get("track_name") or run.meta.get("track") or "")
    if name and Path(name).stem != track.name and name != track.name:
        raise InputError(f"recordings of different tracks: {path} was driven on {name!r}, not on {track.name!r}")
    length = run.meta.get("track_length")
    if length and abs(float(length) - track.length) > 1e-3 * track.length:
        raise InputError(f"recordings of different tracks: {path} has a lap of {float(length):.1f} m, "
                         f"track {track.name!r} {track.length:.1f} m")
    _check_curvature(path, run, track.reversed() if run.meta.get("track_reversed", False) else track)


def _check_curvature(path: Path, run, track) -> None:
    """A gprace run is checked by its ``kappa`` column too: the curvature it recorded along s must
    be the track's (a run of another circuit fails by far)."""
    if "kappa" not in run.data or "s" not in run.data:
        return
    s = np.mod(np.asarray(run["s"], dtype=float), track.length)
    k_run, k_trk = np.asarray(run["kappa"], dtype=float), np.asarray(track.kappa(s), dtype=float)
    typical = max(float(np.percentile(np.abs(k_trk), 90)), 1e-4)
    off = float(np.nanmedian(np.abs(k_run - k_trk)))
    if not off <= CURVATURE_MISMATCH * typical:
        raise InputError(f"recordings of different tracks: {path}: its curvature along s differs from track "
                         f"{track.name!r}'s by {off:.3g} 1/m in the median (the track's typical curvature {typical:.3g} 1/m)")


def import_recordings(paths: list[Path], track, settings: LearnSettings, log=None) -> tuple[list, bool]:
    """Frenet runs of ``paths`` on ``track`` (as its file gives it) and whether they drive it
    against the file's direction (then on the reversed track).

    Raw recordings are imported (map: ``--map``, else ``<name>.map.toml`` beside the file, else the
    defaults); gprace runs (HDF5, Frenet CSV) are read as they are and must name this track.
    InputError (one line) for recordings of another track or driven the other way round."""
    from gprace.ingest.dispatch import sidecar_map
    from gprace.ingest.importer import import_recording
    from gprace.ingest.mapping import load_map
    from gprace.io.runs import read_run

    runs, direction, first = [], None, None
    for p in paths:
        if _is_raw(p):
            mp = Path(settings.map_file) if settings.map_file else (sidecar_map(p) if sidecar_map(p).exists() else None)
            try:
                run, trk = import_recording(p, track=track, rmap=load_map(mp), dt=settings.dt, log=log)
            except InputError as exc:
                if any(w in str(exc) for w in OTHER_TRACK):
                    raise InputError(f"recordings of different tracks: {p} is not a recording of track {track.name!r} "
                                     f"({str(exc).split(': ', 1)[-1]})") from None
                raise
            rev = bool(trk.is_reversed)
            if mp is not None:
                run.meta["map_file"] = str(mp)
        else:
            run = read_run(p)
            _check_run_track(p, run, track)
            rev = bool(run.meta.get("track_reversed", False))
            if abs(run.dt - settings.dt) > 1e-6 * settings.dt:
                raise InputError(f"{p}: recorded every {run.dt:g} s; learn at that period (--dt {run.dt:g})")
        if direction is not None and rev != direction:
            raise InputError(f"{p} drives track {track.name!r} the other way round than {first}")
        direction, first = rev, first or p
        run.meta["track_reversed"] = rev
        runs.append(run)
    return runs, bool(direction)


# ------------------------------------------------------------------------------------------------
# per-recording facts


def usable(run, vehicle) -> tuple[np.ndarray, dict]:
    """The samples a dynamic bicycle model describes (:func:`gprace.io.envelope.envelope`) and
    what was cut, by reason."""
    from gprace.io.envelope import envelope

    keep, rep = envelope(run.data, run.source, wheelbase=vehicle.wheelbase)
    cut: dict[str, int] = {}
    for e in rep.excluded:
        cut[e.reason] = cut.get(e.reason, 0) + int(e.samples)
    return keep, cut


def input_kind(run, name: str = "a_x") -> str:
    """The kind of a recording's input (``meta["inputs"]``, :mod:`gprace.io.runs`); a gprace run
    without it has the commanded ones."""
    given = run.meta.get("inputs") or {}
    if isinstance(given, str):  # stored as JSON text
        given = json.loads(given)
    return str(given.get(name, "commanded"))


def longitudinal_mode(runs) -> str:
    """How the recordings' ``a_x`` drives ``v_x`` in the model (:data:`gprace.model.dynamics.
    LONGITUDINAL`): a commanded ``a_x`` through the forces (``"force"``: gprace runs, a
    powertrain command), a measured or derived one kinematically (``"kinematic"``: it holds every
    longitudinal force, ``dv_x/dt = a_x + r v_y``; the importer derives it so). Recordings of both
    kinds in one iteration are refused (the GPs' ``a_x`` input would mean two things)."""
    kinds = {input_kind(r) == "commanded" for r in runs}
    if len(kinds) > 1:
        raise InputError("the recordings mix a commanded a_x with a measured or derived one; learn them in "
                         "separate --out folders")
    return "force" if kinds == {True} or not kinds else "kinematic"


def recording_facts(run, track, model, keep, cut: dict) -> dict:
    """Laps, the measured envelope, rear-slip use and border hits of one recording, what the
    envelope cut (``cut``: samples by reason), and whether the car completed its laps (at least
    one whole lap, no spin, and a gprace run not ended early)."""
    from gprace.learn.predict import full_laps
    from gprace.sim.record import border_hits
    from gprace.timetrial import grip as G

    ctrl = lambda X: keep  # noqa: E731  (the envelope stands for the in-control rule)
    X = run.states()
    laps = full_laps(run, track.length)
    hits = border_hits(track, X, model.vehicle.length, model.vehicle.width) & keep
    return {"source": run.meta.get("source_file", run.source), "samples": int(run.n), "usable": int(keep.sum()),
            "laps": laps, "best_lap": min(laps) if laps else float("nan"),
            "envelope": G.envelope(run, ctrl).tolist(), "utilisation": G.utilisation(run, model, ctrl),
            "border_hits": int(hits.sum()), "cut": cut, "interventions": int(run.meta.get("interventions", 0)),
            "completed": bool(laps) and not cut.get("spin") and bool(run.meta.get("completed", True)),
            "speed_p5": float(np.percentile(X[keep, 0], 5)) if keep.any() else float("nan")}


# ------------------------------------------------------------------------------------------------
# the iteration


class Iteration:
    """Everything the stages of iteration ``k`` share (loaded once)."""

    def __init__(self, settings: LearnSettings, folder: Folder, k: int, track, model) -> None:
        self.st, self.folder, self.k, self.track, self.model = settings, folder, k, track, model
        self.dir = folder.it(k)
        self._runs = self._keeps = self._facts = None
        self.driven_info: dict | None = None  # --driven of this iteration (the first): its file and limits

    def runs(self) -> list:
        if self._runs is None:
            from gprace.io.runs import read_run

            n = len(read_json(self.dir / "sources.json")["recordings"])
            self._runs = [read_run(self.dir / f"rec_{j}.h5") for j in range(n)]
        return self._runs

    def keeps(self) -> list[np.ndarray]:
        if self._keeps is None:
            self._cuts = [usable(r, self.model.vehicle) for r in self.runs()]
            self._keeps = [k for k, _ in self._cuts]
        return self._keeps

    @property
    def data_model(self):
        """The nominal model whose residuals the GPs learn from these recordings: the second input
        as the recordings have it (:func:`longitudinal_mode`)."""
        from gprace.model import NominalModel

        mode = longitudinal_mode(self.runs())
        return self.model if mode == self.model.params.longitudinal else NominalModel(self.model.vehicle, longitudinal=mode)

    @property
    def facts(self) -> list[dict]:
        """:func:`recording_facts` of every recording of the iteration."""
        if self._facts is None:
            self.keeps()
            self._facts = [recording_facts(r, self.track, self.model, k, cut) for r, (k, cut) in zip(self.runs(), self._cuts)]
        return self._facts

    def previous(self) -> Path | None:
        return self.folder.it(self.k - 1) if self.k > 1 else None

    @property
    def ds(self) -> float:
        return self.st.plan_ds or min(6.0, self.track.length / 250.0)

    @property
    def margin(self) -> float:
        """Planner distance to the borders on top of half the car: 0.3 m, or a quarter of a small car's width."""
        return min(0.3, 0.25 * self.model.vehicle.width)


def stage_import(c: Iteration, checked: Checked) -> None:
    """Write the recordings :func:`check_inputs` imported (and the importer's notes)."""
    from gprace.io.runs import write_run

    for note in checked.notes:
        console.info(note)
    for j, run in enumerate(checked.runs):
        write_run(run, c.dir / f"rec_{j}.h5")


def stage_select(c: Iteration) -> None:
    """Both GPs' dictionaries: this iteration's usable samples streamed into the previous ones."""
    from gprace.gp.dataset import loop_dataset, write_dataset
    from gprace.learn.predict import full_laps
    from gprace.timetrial import learning as L

    st, runs, keeps = c.st, c.runs(), c.keeps()
    model = c.data_model
    for kind in KINDS:
        parts = [L.features(r, model, c.track, kind, st.features, keep=k) for r, k in zip(runs, keeps)]
        Znew = np.vstack([p[0] for p in parts])
        Ynew = np.vstack([p[1] for p in parts])
        if not (c.folder.out / f"hyper_{kind}.h5").exists() and len(Znew) < 20:
            raise InputError(f"the recordings hold only {len(Znew)} usable sample pairs; cannot train the GPs "
                             "(give longer recordings, or check the envelope's cuts)")
        prev = c.previous()
        hyper_path = c.folder.out / f"hyper_{kind}.h5"
        if not hyper_path.exists():
            gp0 = fit_hyper_checked(Znew, Ynew, kind, st)
            L.save_predictor(hyper_path, gp0, kind, feature_set=st.features)
        d, stats = L.stream_step(c.folder.out / f"hyper_{kind}.h5", prev / f"data_{kind}.h5" if prev else None, Znew, Ynew,
                                 kind, st.dictionary_size, st.selection, st.features, st.seed, st.max_fit_points, st.seed + c.k)
        lap_id = np.concatenate([_blocks(len(p[0]), len(full_laps(r, c.track.length)), j) for j, (p, r) in enumerate(zip(parts, runs))])
        write_dataset(c.dir / f"data_{kind}.h5", loop_dataset(
            kind, st.features, d.Z, d.Y,
            {"n_seen": int(d.n_seen), "selection": st.selection, "stats": stats, "longitudinal": model.params.longitudinal},
            {"Z_new": Znew, "Y_new": Ynew, "block_new": lap_id}))


def fit_hyper_checked(Z: np.ndarray, Y: np.ndarray, kind: str, st: LearnSettings):
    """The hyperparameters of the first iteration, as iterate fits them
    (:func:`gprace.timetrial.learning.fit_hyper`, same seed and subsample), checked for a
    degenerate optimum (:func:`gprace.gp.quality.fit_quality`); a degenerate fit is fitted again
    by :func:`gprace.gp.quality.checked_fit` (other seeds, from a reference GP's optimum).
    Measured on the INI run 01-45-24 with the body acceleration as a_x: the single L-BFGS run
    ended with every length scale at its lower bound and the noise at 1 (white noise: the learned
    yaw-rate error equal to the nominal model's, 0.283 against 0.129 before)."""
    from gprace.gp.quality import checked_fit, fit_quality
    from gprace.timetrial import learning as L

    gp0 = L.fit_hyper(Z, Y, seed=st.seed, max_fit_points=st.max_fit_points)
    q = fit_quality(gp0, Z, Y, Z, Y, seed=st.seed, heldout_from_training=True)
    if not q.degenerate:
        return gp0
    console.warn(f"learn: the {kind} GP's hyperparameter fit is degenerate ({q.problems()}); fitted again")
    settings = {"kernel": "se", "optimize": True, "seed": st.seed, "max_fit_points": st.max_fit_points,
                "shared_kernel": True}
    return checked_fit("exact", settings, Z, Y, what=f"learn's {kind} GP")[0]


def _blocks(n: int, laps: int, j: int) -> np.ndarray:
    """Block label (recording * 1000 + block) of ``n`` feature rows in time order: as many
    contiguous blocks as the recording has laps (at least 2), the folds of the calibration."""
    b = max(2, laps)
    return j * 1000 + np.minimum((np.arange(n) * b) // max(n, 1), b - 1).astype(float)


def block_scale(hyper, Zd: np.ndarray, Yd: np.ndarray, Z: np.ndarray, Y: np.ndarray, block: np.ndarray,
                level: float = 0.95) -> np.ndarray:
    """Variance scale (p,) >= 1 that makes the ``level`` band cover that share of each block's
    errors under the GP fitted on the dictionary without that block's points (split-conformal
    across laps: the GP's own leave-one-out errors cannot show a lap it has not seen)."""
    from scipy.stats import norm

    from gprace.timetrial.learning import refit_fixed

    dict_rows = {r.tobytes() for r in np.ascontiguousarray(Zd)}
    zs = []
    for b in np.unique(block):
        inb = block == b
        mine = {r.tobytes() for r in np.ascontiguousarray(Z[inb])} & dict_rows
        out = np.array([r.tobytes() not in mine for r in np.ascontiguousarray(Zd)])
        if out.sum() < 20 or inb.sum() < 5:
            continue
        gp = refit_fixed(hyper, Zd[out], Yd[out])
        mean, var = gp.predict(Z[inb])
        zs.append((Y[inb] - mean) / np.sqrt(var + gp.noise_))
    if not zs:
        return np.ones(Y.shape[1])
    z = np.vstack(zs)
    q = np.quantile(np.abs(z), level, axis=0)
    return np.maximum((q / norm.ppf(0.5 + level / 2)) ** 2, 1.0)


def stage_retrain(c: Iteration) -> dict:
    """Both GPs on their dictionaries with calibrated variances; returns the calibration."""
    from gprace.gp.dataset import read_dataset
    from gprace.timetrial import learning as L

    out = {}
    for kind in KINDS:
        a = read_dataset(c.dir / f"data_{kind}.h5")
        hyper = L.load_predictor(c.folder.out / f"hyper_{kind}.h5", kind).gp
        gp = L.refit_fixed(hyper, a.Z, a.Y)
        loo = L.calibrate(gp)
        laps = block_scale(hyper, a.Z, a.Y, a.extra["Z_new"], a.extra["Y_new"], a.extra["block_new"])
        scale = np.maximum(loo, laps)
        L.save_predictor(c.dir / f"gp_{kind}.h5", gp, kind, {"iteration": c.k, "dt": c.st.dt}, c.st.features, scale)
        out[kind] = {"var_scale": scale.tolist(), "loo_scale": loo.tolist(), "lap_scale": laps.tolist(),
                     "dictionary": int(len(a.Z)), "seen": int(a.attrs["n_seen"]), "new": int(len(a.extra["Z_new"]))}
    return out


def lateral_cap(model, share: float) -> tuple[np.ndarray, str]:
    """The cap of the planner's ellipse: ``share`` of the nominal model's limits; when the model's
    fastest steady corner cannot be solved, its friction ``mu g`` stands for the lateral limit."""
    from gprace.timetrial import grip as G

    try:
        return G.nominal_cap(model, share), ""
    except SolverError as exc:
        lim = model.vehicle.limits
        note = f"the nominal model's steady lateral limit could not be solved ({exc}); mu g stands for it"
        return share * np.array([model.params.mu * model.params.g, lim.accel_max, -lim.accel_min]), note


def driven_plan(c: Iteration):
    """``(plan, limits)`` of ``--driven`` (the plan or raceline the recordings drove) on the track
    in the direction learned, or ``(None, None)``. Its limits: a gprace plan's own, else what its
    speed profile asks for (:func:`gprace.timetrial.grip.envelope_of` over its nodes)."""
    from gprace.timetrial import grip as G
    from gprace.plan.raceline import load_plan

    if not c.st.driven:
        return None, None
    if not Path(c.st.driven).exists():
        raise InputError(f"--driven {c.st.driven}: no such file")
    plan, trk = load_plan(c.st.driven, c.st.track, c.model.vehicle, c.ds)
    if bool(trk.is_reversed) != bool(c.track.is_reversed):
        raise InputError(f"--driven {c.st.driven}: drives the track the other way round than the recordings")
    lim = plan.meta.get("limits")
    if lim is None or len(lim) != 3:
        lim = G.envelope_of(plan.states(), plan.inputs(), plan.t, np.ones(plan.n, bool)).tolist()
    plan.meta = {**plan.meta, "limits": [float(v) for v in lim]}
    return plan, plan.meta["limits"]


def lap_records(c: Iteration, facts: list[dict]) -> list[dict]:
    """The laps of the loop so far as ``iterate`` records them: lap ``j`` is plan ``j`` driven in
    the recordings of iteration ``j + 1`` (plan 0 the car's own: ``--driven`` of iteration 1, or
    unknown); ``facts`` are this iteration's recordings (the last lap). Each: ``completed``,
    ``driven`` (best lap [s]), ``alpha``, ``limits`` (the plan's; lap 0 without a known plan: the
    envelope its recordings measured), ``plan`` (its file or None), ``known`` (the plan's limits
    are known) and ``status`` (:func:`gprace.timetrial.guard.lap_status`)."""
    from gprace.timetrial.guard import lap_status

    recs: list[dict] = []
    for j in range(c.k):
        fs = facts if j + 1 == c.k else c.folder.record(j + 1)["recordings"]
        laps = [t for f in fs for t in f["laps"]]
        if j == 0:
            d = (c.folder.record(1).get("driven") if c.k > 1 else c.driven_info) or {}
            plan = c.folder.it(1) / "driven.h5" if d.get("limits") else None
            limits = d.get("limits") or np.max(np.array([f["envelope"] for f in fs], float), axis=0).tolist()
            alpha = 0.0
        else:
            rec = c.folder.record(j)
            plan, limits, alpha = c.folder.it(j) / "plan.h5", rec["limits"], float(rec["settings"].get("alpha") or 0.0)
        r = {"completed": all(f["completed"] for f in fs), "driven": min(laps) if laps else float("nan"),
             "alpha": alpha, "limits": [float(v) for v in limits], "plan": plan, "known": plan is not None}
        r["status"] = lap_status(r, recs, c.st.slower_tolerance)
        recs.append(r)
    return recs


def next_plan_limits(c: Iteration, facts: list[dict]) -> dict:
    """The friction ellipse of the next plan, by ``iterate``'s rules (``gprace.timetrial``'s
    functions): :func:`~gprace.timetrial.grip.next_limits` from the last plan's limits and the
    envelope, rear-slip use, border hits and interventions of this iteration's recordings; with
    ``never_worse``, after a lost or slower lap the last good plan's limits again
    (:mod:`gprace.timetrial.guard`), never a level that lost the car. The first plan of the car
    unknown (no ``--driven``), a completed first lap is planned at its measured envelope, not
    widened: the envelope holds transients above what the plan asked for (Norisring: planned at
    10.4 m/s^2 lateral, measured 12.03)."""
    from gprace.timetrial import grip as G
    from gprace.timetrial import guard

    st = c.st
    measured = np.max(np.array([f["envelope"] for f in facts], float), axis=0)
    if not np.all(np.isfinite(measured)):
        raise InputError("the recordings hold too few usable samples to measure the car's envelope")
    util = float(np.nanmax([f["utilisation"] for f in facts])) if facts else float("nan")
    completed = all(f["completed"] for f in facts)
    hits = int(sum(f["border_hits"] for f in facts))
    inter = int(sum(f.get("interventions", 0) for f in facts))
    cap, note = lateral_cap(c.model, st.plan_grip)
    laps = lap_records(c, facts)
    last = laps[-1]
    failed = [r["limits"] for r in laps if not r["completed"]]
    previous = np.asarray(last["limits"], float)
    ref = guard.last_good(laps) if st.never_worse else None
    shown = None
    if st.never_worse and last["status"] != "good" and ref is not None:
        limits = G.below_failed(laps[ref]["limits"], failed, st.widen)
        source = f"back to the limits of lap {ref}" + ("" if G.clear_of(laps[ref]["limits"], failed, st.widen)
                                                      else ", below the limits of the lost laps")
    else:
        widen = st.widen if last["known"] or not completed else 0.0
        limits = G.next_limits(previous, measured, completed, util, cap, widen, failed=failed, border_hits=hits,
                               interventions=inter if c.k > 1 else 0,
                               widen_max=st.widen_max if last["known"] else widen, shape=c.model.params.cr)
        source = "replan"
        shown = grip_shown(c, completed)
        if shown is not None:  # never plan corners faster than the grip the car has shown (as iterate)
            over = G.overshoot([(measured, previous, 1.0)] if completed and last["known"] else [])
            limits[0] = min(limits[0], G.shown_limit(shown, lateral_cap(c.model, 1.0)[0][0], over, float(previous[0])))
    start = start_lap(laps, st.never_worse, st.widen)
    return {"limits": np.asarray(limits, float).tolist(), "previous": previous.tolist(), "measured": measured.tolist(),
            "cap": cap.tolist(), "utilisation": util, "border_hits": hits, "interventions": inter,
            "completed": completed, "failed": failed, "grip_shown": shown, "note": note, "source": source,
            "start": start, "status": [r["status"] for r in laps], "previous_known": bool(last["known"])}


def grip_shown(c: Iteration, completed: bool) -> float | None:
    """The weakest axle's grip against the nominal tire (:func:`gprace.timetrial.shakedown.axle_grip`,
    in-control samples) over the recordings of every iteration whose laps completed (``completed``:
    this iteration's), or None. ``iterate`` caps its lateral limit with it (a BMW with a worn rear
    spun at the hairpin without it); learn applies the same rule."""
    from gprace.io.runs import read_run
    from gprace.timetrial.learning import in_control
    from gprace.timetrial.shakedown import axle_grip

    ratios: list[float] = []
    for j in range(1, c.k + 1):
        if not (completed if j == c.k else c.folder.record(j)["completed"]):
            continue
        runs = c.runs() if j == c.k else [read_run(p) for p in sorted(c.folder.it(j).glob("rec_*.h5"))]
        for run in runs:
            X = run.states()
            ratios += list(axle_grip(X, run.inputs(), run.dt, c.model, in_control(X)).values())
    ratios = [r for r in ratios if np.isfinite(r)]
    return float(min(ratios)) if ratios else None


def start_lap(laps: list[dict], never_worse: bool, widen: float) -> int | None:
    """The lap whose plan the next one starts from (and writes again when the new plan fails or,
    with ``never_worse``, is not predicted safe), as iterate: the last good lap whose limits stay
    clear of every lost lap's (:func:`gprace.timetrial.guard.last_good`), else the last completed
    one; None when that lap's plan is unknown or no lap completed (the curvature line). A plan
    that lost its lap is never the one."""
    from gprace.timetrial import grip as G
    from gprace.timetrial import guard

    failed = [r["limits"] for r in laps if not r["completed"]]
    ref = guard.last_good(laps, clear=lambda lim: G.clear_of(lim, failed, widen)) if never_worse else None
    good = [j for j in range(len(laps) - 1, -1, -1) if laps[j]["completed"]]
    start = ref if ref is not None else (good[0] if good else None)
    return None if start is None or laps[start]["plan"] is None else start


def stage_plan(c: Iteration, lim: dict) -> dict:
    """The minimum-time plan with the planning GP inside the new limits, warm-started from the
    plan :func:`next_plan_limits` chose (the last good one, as iterate; none: the curvature-optimal
    line at the limits). With ``never_worse`` a plan the guard does not predict safe
    (:func:`gprace.timetrial.guard.plan_safety`) is replaced by that plan; a failed solve writes it
    again. A plan that lost its lap is never written again (measured on Norisring: a lost lap
    narrowed the limits, the lost plan was an infeasible warm start, IPOPT stopped at 1500
    iterations and the lost plan was driven again)."""
    from gprace.mpc.tracking import MPCSettings
    from gprace.plan import PlanSettings, curvature_plan, plan_min_time, read_plan
    from gprace.timetrial import guard
    from gprace.timetrial import learning as L

    track, model = c.track, c.model
    start = lim.get("start")
    limits = lim["limits"]
    warm = read_plan(_lap_plan(c, start), track) if start is not None else None
    speeds = [f["speed_p5"] for f in c.facts]
    v_low = float(min(3.0, 0.5 * np.nanmin(speeds))) if np.any(np.isfinite(speeds)) else 3.0
    gp_plan = L.load_predictor(c.dir / "gp_planning.h5", "planning")
    info = {"replan_failed": "", "unsafe": "", "safety": {},
            "warm_start": "curvature" if start is None else f"the plan of lap {start}"}
    what = f"the plan of lap {start} (the last good one)" if start is not None else "the curvature-optimal line at the limits"
    try:
        plan = plan_min_time(track, model, PlanSettings(ds=c.ds, limits=tuple(limits), margin=c.margin, v_low=max(v_low, 0.1)),
                             warm=warm or curvature_plan(track, model, ds=c.ds, speed_scale=1.0, margin=c.margin, a_lat=limits[0]),
                             mu_plan=lambda X, U: gp_plan.at(X, U)[0])
        if c.st.never_worse:
            safety = guard.plan_safety(plan, model, gp_plan, MPCSettings(dt=c.st.dt).grip_share)
            info["safety"] = {k: v for k, v in safety.items() if k != "safe"}
            if not safety["safe"] and warm is not None:
                info["unsafe"] = safety["why"]
                console.warn(f"learn: the new plan is not predicted safe ({safety['why']}); {what} is written instead")
                plan, limits = warm, warm.meta.get("limits", limits)
    except SolverError as exc:
        plan = warm or curvature_plan(track, model, ds=c.ds, speed_scale=1.0, margin=c.margin, a_lat=limits[0])
        info["replan_failed"] = str(exc)
        console.warn(f"learn: the re-plan failed ({exc}); {what} is written instead")
        limits = plan.meta.get("limits", limits)
    plan.meta = {**plan.meta, "limits": [float(v) for v in limits], "iteration": c.k,
                 "replan_failed": info["replan_failed"], "unsafe": info["unsafe"]}
    plan.write(c.dir / "plan.h5")
    return {"planned_lap_time": float(plan.lap_time), "limits": plan.meta["limits"], **info}


def _lap_plan(c: Iteration, j: int) -> Path:
    """The file of the plan of lap ``j`` (:func:`lap_records`)."""
    return c.folder.it(1) / "driven.h5" if j == 0 else c.folder.it(j) / "plan.h5"


def stage_export(c: Iteration) -> dict:
    """Racelines (TUM, F1TENTH), the portable tracking GP; with alpha the exploration candidates
    and the reference of Algorithm 1 along the plan. Returns the files and their sha256."""
    from gprace.gp.export import export_gp
    from gprace.plan import read_plan
    from gprace.timetrial import learning as L
    from gprace.tracks.raceline import SUFFIXES, raceline_of_plan, write_raceline

    plan = read_plan(c.dir / "plan.h5", c.track)
    rl = raceline_of_plan(plan, c.track)
    head = (f"gprace learn iteration {c.k}: car {c.model.vehicle.name}, track {c.track.name}",
            f"planned lap {plan.lap_time:.3f} s")
    files = []
    for fmt, name in SUFFIXES.items():
        write_raceline(c.dir / name, rl, fmt, head)
        files.append(name)
    gp = L.load_predictor(c.dir / "gp_tracking.h5", "tracking")
    export_gp(gp, c.dir / "gp_tracking.portable.h5", c.dir / "gp_tracking.card.json", dt=c.st.dt,
              step=f"RK4 of the nominal model over dt, curvature following s (gprace.timetrial.learning.features); "
                   f"a_x read {'as the powertrain command (force model)' if c.data_model.params.longitudinal == 'force' else 'as the body acceleration (kinematic: dv_x/dt = a_x + r v_y)'}",
              vehicle=c.model.vehicle, provenance={"iteration": c.k, "out": str(c.folder.out)})
    files += ["gp_tracking.portable.h5", "gp_tracking.card.json"]
    if c.st.alpha is not None:
        files += exploration_reference(c, plan, gp)
    return {f: file_sha(c.dir / f) for f in files}


def exploration_reference(c: Iteration, plan, gp) -> list[str]:
    """Algorithm 1's candidates (``candidates.h5``) and, along the plan, the reference the tracking
    MPC would follow with ``alpha`` (``explore_reference.csv``: where it explores, the target
    lateral velocity, yaw rate and steering replace the plan's)."""
    from gprace.gp.dataset import read_dataset
    from gprace.io.artifacts import Artifact, write_artifact, write_text_atomic
    from gprace.mpc.tracking import MPCSettings, TrackingMPC
    from gprace.timetrial.iterate import make_grid

    mpc = MPCSettings(dt=c.st.dt)
    grid = make_grid(gp.gp, read_dataset(c.dir / "data_tracking.h5").Z, mpc, c.st.grid_values)
    write_artifact(c.dir / "candidates.h5", Artifact("candidates", {"Z": grid.Z, "v": grid.v, "scale": grid.scale},
                                                      {"alpha": float(c.st.alpha), "inputs": list(gp.inputs)}))
    ctl = TrackingMPC(c.model, c.track, plan, mpc, gp=gp, grid=grid, alpha=float(c.st.alpha))
    rows = []
    for k in range(plan.n):  # once per node of the plan, offline
        X, U = plan.at_time(plan.t[k] + mpc.dt * np.arange(mpc.N + 1))
        ctl.last_target = None
        Xe, Ue = ctl.explore(X, U)
        x, y = c.track.to_global(plan.s[k], Xe[0, 4])
        rows.append([plan.s[k], float(x), float(y), Xe[0, 0], Xe[0, 1], Xe[0, 2], Ue[0, 0], Ue[0, 1],
                     float(ctl.last_target is not None)])
    head = "s_m,x_m,y_m,vx_mps,vy_mps,yaw_rate_radps,delta_rad,ax_mps2,explore"
    body = "\n".join(",".join(f"{v:.6f}" for v in r) for r in rows)
    write_text_atomic(c.dir / "explore_reference.csv", head + "\n" + body + "\n")
    return ["candidates.h5", "explore_reference.csv"]


def stage_predict(c: Iteration, limits) -> dict:
    """The prediction of the next lap (``prediction.h5``) and its summary."""
    from gprace.learn.predict import grip_places, predict
    from gprace.mpc.tracking import MPCSettings
    from gprace.plan import read_plan
    from gprace.timetrial import learning as L

    plan = read_plan(c.dir / "plan.h5", c.track)
    gp = L.load_predictor(c.dir / "gp_tracking.h5", "tracking")
    pred = predict(plan, c.track, c.model, gp, c.st.dt, MPCSettings().N, limits)
    pred.write(c.dir / "prediction.h5")
    return {"lap_time": pred.lap_time, "grip_places": grip_places(plan, pred.use, limits),
            "band_median_m": float(np.median(pred.band)), "band_max_m": float(pred.band.max()),
            "band_max_at_s": float(pred.s[np.argmax(pred.band)])}


# ------------------------------------------------------------------------------------------------
# the command


class Checked(NamedTuple):
    """What :func:`check_inputs` found: the recordings imported onto ``track`` (as its file gives
    it) and whether they drive it the other way round."""

    paths: list[Path]
    folder: Folder
    vehicle: Any
    track: Any
    runs: list
    reversed: bool
    notes: list[str]


def check_inputs(paths, settings: LearnSettings, out) -> Checked:
    """Refuse, before the command's start line (a refusal is one line): recordings that do not
    exist, an ``out`` that is not this car's learn folder, a vehicle or open track that does not
    load, recordings of another track or driven the other way round than earlier iterations. The
    recordings are imported here, once (a raw log shows its track only when imported)."""
    from gprace.model import load_vehicle
    from gprace.io.artifacts import check_folder
    from gprace.tracks import load_track

    paths = [Path(p) for p in paths]
    if not paths:
        raise InputError("learn: give at least one RECORDING")
    for p in paths:
        if not p.exists():
            raise InputError(f"{p}: no such file")
    check_folder(out)
    vehicle = load_vehicle(settings.vehicle)
    track0 = load_track(settings.track)
    if not track0.closed:
        raise InputError(f"--track {settings.track}: an open track; learning a lap needs a closed one")
    folder = Folder(Path(out))
    learned = folder.out / "learn.json"
    was = bool(read_json(learned).get("track_reversed")) if learned.exists() else None
    check_identity(folder, car_identity(vehicle, track0.reversed() if was else track0, settings))  # refuses an iterate folder
    if settings.driven:
        if not Path(settings.driven).exists():
            raise InputError(f"--driven {settings.driven}: no such file")
        k, _ = choose_iteration(folder, [{"path": str(p), "sha256": file_sha(p)} for p in paths])
        if k > 1:
            raise InputError(f"--driven: the recordings of iteration {k} drove iteration {k - 1}'s raceline; "
                             "--driven names the car's own plan of the first iteration only")
    notes: list[str] = []
    runs, rev = import_recordings(paths, track0, settings, log=notes.append)
    if was is not None and rev != was:
        raise InputError(f"{paths[0]} drives track {track0.name!r} the other way round than the iterations in "
                         f"{folder.out}; use another --out")
    return Checked(paths, folder, vehicle, track0, runs, rev, notes)


def learn(paths, settings: LearnSettings, out, progress=None, checked: Checked | None = None) -> dict:
    """Run (or resume) the iteration of ``paths`` in ``out`` (``checked``: what
    :func:`check_inputs` found, if the caller checked already); returns its record."""
    from gprace.model import NominalModel

    checked = checked or check_inputs(paths, settings, out)
    paths, folder, vehicle, track0 = checked.paths, checked.folder, checked.vehicle, checked.track
    model = NominalModel(vehicle)
    sources = [{"path": str(p), "sha256": file_sha(p)} for p in paths]
    k, new = choose_iteration(folder, sources)
    done = (not new) and folder.finished(k)
    learned = folder.out / "learn.json"  # the direction earlier iterations learned in (checked above)
    track = (track0.reversed() if read_json(learned).get("track_reversed") else track0) if learned.exists() else None
    adv = progress or (lambda name: None)
    c = None
    if not done:
        folder.it(k).mkdir(parents=True, exist_ok=True)
        if new:
            write_json(folder.it(k) / "sources.json", {"recordings": sources})
        # 1. import: the track's direction comes from the recordings
        if not folder.done(k, "import"):
            console.info(f"learn: iteration {k}: {len(paths)} recording(s) imported")
            c = Iteration(settings, folder, k, track or track0, model)
            stage_import(c, checked)
            folder.mark(k, "import")
        adv("import")
        if track is None:
            track = track0.reversed() if checked.reversed else track0
            write_json(folder.out / "learn.json", car_identity(vehicle, track, settings))
        c = Iteration(settings, folder, k, track, model)
        stages = {"select": lambda: stage_select(c), "retrain": lambda: stage_retrain(c)}
        results = _partial(folder, k)
        for name in ("select", "retrain"):
            if not folder.done(k, name):
                console.info(f"learn: iteration {k}: {name}")
                r = stages[name]()
                if r is not None:
                    results[name] = r
                    _save_partial(folder, k, results)
                folder.mark(k, name)
            adv(name)
        if not folder.done(k, "plan"):
            _plan_stage(c, results)
        adv("plan")
        if not folder.done(k, "export"):
            console.info(f"learn: iteration {k}: export (racelines, portable GP{', exploration' if settings.alpha is not None else ''})")
            results["exports"] = stage_export(c)
            _save_partial(folder, k, results)
            folder.mark(k, "export")
        adv("export")
        console.info(f"learn: iteration {k}: predict (the GP's band along the lap)")
        results["prediction"] = stage_predict(c, results["plan"]["limits"])
        write_json(folder.it(k) / "record.json",
                   _record(c, sources if new else read_json(folder.it(k) / "sources.json")["recordings"], vehicle, results))
        folder.mark(k, "predict")
        adv("predict")
    else:
        for s in STAGES:
            adv(s)
    rec = folder.record(k)
    rec["already_done"] = done
    return rec


def _plan_stage(c: Iteration, results: dict) -> None:
    """The plan stage of an iteration: the driven raceline's plan (``--driven``, once), the
    limits of the next plan from the laps, the minimum-time plan; saved with the stage results."""
    console.info(f"learn: iteration {c.k}: plan (minimum-time NLP with the planning GP)")
    st = c.st
    if st.driven and "driven" not in results:
        plan_d, lim_d = driven_plan(c)
        plan_d.write(c.dir / "driven.h5")
        results["driven"] = {"path": st.driven, "sha256": file_sha(Path(st.driven)), "limits": lim_d}
    c.driven_info = results.get("driven")
    results["grip"] = next_plan_limits(c, c.facts)
    results["plan"] = stage_plan(c, results["grip"])
    _save_partial(c.folder, c.k, results)
    c.folder.mark(c.k, "plan")


def _record(c: Iteration, sources: list[dict], vehicle, results: dict) -> dict:
    """The iteration's ``record.json``: its recordings (with what the import found), the plan's
    limits, the car, the track, the settings and every stage's results."""
    from gprace import __version__

    track, settings = c.track, c.st
    return {
        "version": LEARN_VERSION, "iteration": c.k, "gprace_version": __version__,
        "created": time.strftime("%Y-%m-%dT%H:%M:%S"), "out": str(c.folder.out),
        "recordings": [{**s, **f, "import": r.meta.get("source_format", "gprace run"),
                        "notes": list(r.meta.get("notes", []))}
                       for s, f, r in zip(sources, c.facts, c.runs())],
        "completed": results["grip"]["completed"], "limits": results["plan"]["limits"],
        "vehicle": {"name": vehicle.name, "config_hash": vehicle.digest(), "source": settings.vehicle},
        "track": {"name": track.name, "spec": settings.track, "reversed": bool(track.is_reversed),
                  "length": track.length, "hash": car_identity(vehicle, track, settings)["track_hash"]},
        "settings": settings.model_dump(mode="json"), **results,
    }


def _partial(folder: Folder, k: int) -> dict:
    p = folder.it(k) / "stages.json"
    return read_json(p) if p.exists() else {}


def _save_partial(folder: Folder, k: int, results: dict) -> None:
    write_json(folder.it(k) / "stages.json", results)


# ------------------------------------------------------------------------------------------------
# after the next lap


def learned_track(folder: Folder):
    """The track an ``--out`` folder learned on, in the direction it is driven, and its identity."""
    from gprace.tracks import load_track

    path = folder.out / "learn.json"
    if not path.exists():
        raise InputError(f"{folder.out}: not a gprace learn folder (no learn.json)")
    ident = read_json(path)
    track = load_track(ident["track_spec"])
    track = track.reversed() if ident.get("track_reversed") else track
    from gprace.plan import track_hash

    if track_hash(track) != ident["track_hash"]:
        raise InputError(f"{folder.out}: its track {ident['track_spec']} has changed since it was learned on")
    return track, ident


def evaluate_learn(out, log, iteration: int | None = None, map_file=None) -> dict:
    """The next recorded log against an iteration's prediction (:func:`gprace.learn.predict.compare_laps`)."""
    from gprace.model import load_vehicle
    from gprace.learn.predict import Prediction, compare_laps
    from gprace.tracks import load_track

    folder = Folder(Path(out))
    track, ident = learned_track(folder)
    done = [k for k in folder.iterations() if folder.finished(k)]
    if not done:
        raise InputError(f"{folder.out}: no finished iteration")
    k = done[-1] if iteration is None else iteration
    if k not in done:
        raise InputError(f"--iteration {k}: {folder.out} has finished iterations {', '.join(map(str, done))}")
    rec = folder.record(k)
    st = LearnSettings(**{**rec["settings"], "map_file": str(map_file) if map_file else rec["settings"].get("map_file")})
    vehicle = load_vehicle(rec["vehicle"]["source"])
    runs, rev = import_recordings([Path(log)], load_track(ident["track_spec"]), st)
    if rev != bool(ident.get("track_reversed")):
        raise InputError(f"{log} drives the track the other way round than {folder.out}'s iterations")
    run = runs[0]
    keep, cut = usable(run, vehicle)
    res = compare_laps(Prediction.read(folder.it(k) / "prediction.h5"), run, keep)
    return {"iteration": k, "log": str(log), "cut": cut, **res}


def write_mcap(out: Path, k: int, path: Path) -> Path:
    """The iteration's recordings, its plan with the GP's band and the track as MCAP
    (:mod:`gprace.io.foxglove`)."""
    from gprace.io.foxglove import ALONG_FIELDS, write_runs
    from gprace.io.runs import read_run
    from gprace.learn.predict import Prediction
    from gprace.plan import read_plan

    folder = Folder(out)
    track, _ = learned_track(folder)
    d = folder.it(k)
    rec = folder.record(k)
    pred = Prediction.read(d / "prediction.h5")
    plan = read_plan(d / "plan.h5", track)
    runs = {f"recording_{j}": read_run(d / f"rec_{j}.h5") for j in range(len(rec["recordings"]))}
    along = {f: getattr(pred, f) for f in ALONG_FIELDS}
    notes = [f"gprace learn iteration {k}: predicted lap {rec['plan']['planned_lap_time']:.3f} s"]
    notes += [f"grip used most at s {g['s_start']:.1f}..{g['s_end']:.1f} m ({100 * g['use']:.0f} %)"
              for g in rec["prediction"]["grip_places"]]
    return write_runs(path, track, runs, {f"iteration_{k}": (plan, along, pred.band)}, notes)
