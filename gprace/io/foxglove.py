"""Laps, plans, the GP's band and the track as an MCAP file with Foxglove's standard schemas.

Written with foxglove-sdk (PyPI ``foxglove-sdk``), readable by Foxglove and by the ``mcap`` reader.
Everything is in the track's global frame ``world`` (metres); log times are the run's own times
(seconds from its start) in nanoseconds. Topics:

==========================  ======================  ============================================
``/track``                  foxglove.SceneUpdate    centre line (entity ``centre``), borders
                                                    (``left``, ``right``), at time 0
``/plan/<name>``            foxglove.SceneUpdate    a planned line (``line``) and, with a band,
                                                    its edges (``band_left``, ``band_right``)
``/plan/<name>/path``       foxglove.PosesInFrame   the planned line as poses (heading of travel)
``/plan/<name>/along``      gprace.PlanAlong (JSON) per node: s, speed, band, GP std, grip use
``/run/<name>/pose``        foxglove.PoseInFrame    the recorded car, one message per sample
``/run/<name>/state``       gprace.RunState (JSON)  per sample: t, s, e_y, v_x, v_y, yaw_rate,
                                                    delta, a_x
``/log``                    foxglove.Log            what wrote the file, one line per fact
==========================  ======================  ============================================

What writes them: ``learn --mcap`` (the iteration's recordings, its plan ``iteration_<k>`` with
the band), ``run --mcap`` (the plan ``plan``, with the band when driven with a tracking GP, and
the run ``run``), ``iterate --mcap`` (every trial's plans and laps, ``trial_<j>/iter_<i>``, the
band on the iterations driven with a GP, and the oracle lap). This module writes laps and plans
given to it; :mod:`gprace.report.mcap` gathers them from a run or an iterate folder.

Heavy imports (foxglove) happen in :class:`McapLog` only.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

STATE_FIELDS = ("t", "s", "e_y", "v_x", "v_y", "yaw_rate", "delta", "a_x")
ALONG_FIELDS = ("s", "x", "y", "speed", "band", "sigma_vy", "sigma_r", "use")
FRAME = "world"
COLORS = {"track": (0.25, 0.25, 0.25, 1.0), "centre": (0.5, 0.5, 0.5, 0.8), "plan": (0.1, 0.45, 0.9, 1.0),
          "band": (0.1, 0.45, 0.9, 0.45)}


def _schema(name: str, fields):
    """A named JSON schema of an object of numbers (Foxglove's plot panels read any numeric field)."""
    import json

    from foxglove import Schema

    body = {"title": name, "type": "object", "properties": {f: {"type": "number"} for f in fields}, "required": list(fields)}
    return Schema(name=name, encoding="jsonschema", data=json.dumps(body).encode())


class McapLog:
    """An MCAP file being written (a context manager); one Foxglove context of its own, so two
    files written in one process do not share channels."""

    def __init__(self, path: str | Path) -> None:
        import foxglove

        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = self.path.with_name(f".{self.path.name}.tmp")
        self._ctx = foxglove.Context()
        self._writer = foxglove.open_mcap(self._tmp, allow_overwrite=True, context=self._ctx)
        self._channels: dict[str, object] = {}

    def __enter__(self) -> McapLog:
        return self

    def __exit__(self, *exc) -> None:
        self.close(commit=exc[0] is None)

    def close(self, commit: bool = True) -> None:
        self._writer.close()
        if commit:
            self._tmp.replace(self.path)
        else:
            self._tmp.unlink(missing_ok=True)

    # channels ------------------------------------------------------------------------------------
    def _typed(self, topic: str, kind: str):
        from foxglove import channels

        if topic not in self._channels:
            self._channels[topic] = getattr(channels, f"{kind}Channel")(topic, context=self._ctx)
        return self._channels[topic]

    def _json(self, topic: str, name: str, fields):
        from foxglove import Channel

        if topic not in self._channels:
            self._channels[topic] = Channel(topic, schema=_schema(name, fields), message_encoding="json", context=self._ctx)
        return self._channels[topic]

    # content ---------------------------------------------------------------------------------------
    def track(self, track) -> None:
        """Centre line and borders (closed loops) on ``/track``."""
        smp = track.sample(min(track.length / 2000, 1.0))
        (xl, yl), (xr, yr) = track.borders()
        ents = [self._entity("centre", smp.x, smp.y, COLORS["centre"], track.closed),
                self._entity("left", xl, yl, COLORS["track"], track.closed),
                self._entity("right", xr, yr, COLORS["track"], track.closed)]
        self._scene("/track", ents, 0.0)

    def plan(self, name: str, x, y, heading, along: dict | None = None, band_edges=None) -> None:
        """A planned line: scene lines (and band edges), its poses, and per-node values ``along``."""
        from foxglove.messages import PosesInFrame

        ents = [self._entity("line", x, y, COLORS["plan"], True)]
        if band_edges is not None:
            (xl, yl), (xr, yr) = band_edges
            ents += [self._entity("band_left", xl, yl, COLORS["band"], True),
                     self._entity("band_right", xr, yr, COLORS["band"], True)]
        self._scene(f"/plan/{name}", ents, 0.0)
        poses = [self._pose(a, b, h) for a, b, h in zip(x, y, heading)]
        self._typed(f"/plan/{name}/path", "PosesInFrame").log(
            PosesInFrame(timestamp=self._stamp(0.0), frame_id=FRAME, poses=poses), log_time=0)
        if along:
            ch = self._json(f"/plan/{name}/along", "gprace.PlanAlong", list(along))
            cols = {k: np.asarray(v, float) for k, v in along.items()}
            for i in range(len(next(iter(cols.values())))):  # one message per node
                ch.log({k: float(v[i]) for k, v in cols.items()}, log_time=i)

    def run(self, name: str, t, x, y, yaw, state: dict) -> None:
        """A recorded (or simulated) drive: the car's pose and state per sample, at its own time."""
        from foxglove.messages import PoseInFrame

        pose = self._typed(f"/run/{name}/pose", "PoseInFrame")
        ch = self._json(f"/run/{name}/state", "gprace.RunState", list(state))
        cols = {k: np.asarray(v, float) for k, v in state.items()}
        ns = (np.asarray(t, float) * 1e9).astype(np.int64)
        for i in range(len(ns)):  # one message per sample and topic
            pose.log(PoseInFrame(timestamp=self._stamp(t[i]), frame_id=FRAME, pose=self._pose(x[i], y[i], yaw[i])),
                     log_time=int(ns[i]))
            ch.log({k: float(v[i]) for k, v in cols.items()}, log_time=int(ns[i]))

    def note(self, text: str, t: float = 0.0) -> None:
        from foxglove.messages import Log, LogLevel

        self._typed("/log", "Log").log(Log(timestamp=self._stamp(t), level=LogLevel.Info, message=text, name="gprace"),
                                       log_time=int(t * 1e9))

    # helpers ---------------------------------------------------------------------------------------
    @staticmethod
    def _stamp(t: float):
        from foxglove.messages import Timestamp

        sec = int(np.floor(t))
        return Timestamp(sec, int(round((t - sec) * 1e9)) % 1_000_000_000)

    @staticmethod
    def _pose(x: float, y: float, yaw: float):
        from foxglove.messages import Pose, Quaternion, Vector3

        return Pose(position=Vector3(x=float(x), y=float(y), z=0.0),
                    orientation=Quaternion(x=0.0, y=0.0, z=float(np.sin(yaw / 2)), w=float(np.cos(yaw / 2))))

    @staticmethod
    def _entity(eid: str, x, y, color, closed: bool):
        from foxglove.messages import Color, LinePrimitive, LinePrimitiveLineType, Point3, SceneEntity

        line = LinePrimitive(type=LinePrimitiveLineType.LineLoop if closed else LinePrimitiveLineType.LineStrip,
                             thickness=2.0, scale_invariant=True,
                             points=[Point3(x=float(a), y=float(b), z=0.0) for a, b in zip(x, y)],
                             color=Color(r=color[0], g=color[1], b=color[2], a=color[3]))
        return SceneEntity(frame_id=FRAME, id=eid, lines=[line])

    def _scene(self, topic: str, entities, t: float) -> None:
        from foxglove.messages import SceneUpdate

        self._typed(topic, "SceneUpdate").log(SceneUpdate(entities=entities), log_time=int(t * 1e9))


def run_pose(run, track) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Global ``x, y, yaw`` of a run: its own columns when it has them (an imported log), else from
    its Frenet state on ``track``."""
    if all(c in run.data for c in ("x", "y", "yaw")):
        return np.asarray(run["x"]), np.asarray(run["y"]), np.asarray(run["yaw"])
    x, y = track.to_global(run["s"], run["e_y"])
    return x, y, track.heading(run["s"]) + np.asarray(run["e_psi"])


def write_runs(path, track, runs: dict, plans: dict | None = None, notes=()) -> Path:
    """An MCAP of ``track``, the ``runs`` ``{name: Run}`` and the ``plans`` ``{name: (Plan, along
    dict or None, band (n,) or None)}``; the commands' one call."""
    with McapLog(path) as m:
        m.track(track)
        for name, (plan, along, band) in (plans or {}).items():
            x, y = track.to_global(plan.s, plan.e_y)
            heading = track.heading(plan.s) + plan.e_psi + np.arctan2(plan.v_y, plan.v_x)
            edges = None
            if band is not None:
                edges = (track.to_global(plan.s, plan.e_y + band), track.to_global(plan.s, plan.e_y - band))
            m.plan(name, x, y, heading, along, edges)
        for name, run in runs.items():
            x, y, yaw = run_pose(run, track)
            m.run(name, run["t"], x, y, yaw, {k: run[k] for k in STATE_FIELDS})
        for text in notes:
            m.note(text)
    return Path(path)
