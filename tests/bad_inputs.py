"""Classes of bad input and the commands they are given to, shared by ``test_bad_inputs.py``
(property-based, hypothesis) and ``benchmarks/bad_input_probe.py`` (the count per command).

Every maker writes one bad file (or names a setting) into a folder and returns the argument it
gives the command; :data:`CASES` pairs them with a command line and what must happen:

- ``Refused(needles)``: exit 2, exactly one line on stderr (``error: ...``) holding every needle,
  no output file left behind;
- ``Excluded(needles)``: recoverable data, exit 0 and the documented exclusion note
  ("outside the model's envelope ...") as the only warning.

A recording is a small CSV run (0.3 laps of circle_100, weaving) that the command accepts as it
is; each class of bad data changes it in one way.
"""

from __future__ import annotations

import contextlib
import csv
import io
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from gprace.cli import main
from gprace.config import configs_dir

# ------------------------------------------------------------------------------------------------
# expectations


@dataclass(frozen=True)
class Refused:
    needles: tuple[str, ...] = ()


@dataclass(frozen=True)
class Excluded:
    needles: tuple[str, ...] = ()


@dataclass
class Outcome:
    code: int
    stderr: list[str]
    left_behind: list[str]

    @property
    def one_line(self) -> bool:
        return len(self.stderr) == 1

    def problems(self, expect: Refused | Excluded) -> list[str]:
        """What breaks the contract (empty when the command behaved)."""
        bad = []
        notes = [ln for ln in self.stderr if ln.startswith(("error:", "warning:"))]
        if isinstance(expect, Refused):
            if self.code != 2:
                bad.append(f"exit {self.code}, not 2")
            if not self.one_line or not self.stderr[0].startswith("error: "):
                bad.append(f"{len(self.stderr)} stderr lines, not one error line")
            if self.left_behind:
                bad.append(f"left behind: {self.left_behind}")
        else:
            if self.code != 0:
                bad.append(f"exit {self.code}, not 0")
            if len(notes) != 1 or not notes[0].startswith("warning: ") or "outside the model's envelope" not in notes[0]:
                bad.append(f"not one exclusion note: {notes}")
        text = " ".join(notes)
        bad += [f"{n!r} not in the message" for n in expect.needles if n not in text]
        return bad


def run_cli(argv: list, out_dir: Path) -> Outcome:
    """``gprace argv`` in-process (stdout and stderr captured); its stderr lines and what is in
    ``out_dir`` afterwards."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in argv])
    lines = [ln for ln in err.getvalue().splitlines() if ln.strip()]
    left = sorted(p.name for p in out_dir.iterdir()) if out_dir.exists() else []
    return Outcome(code, lines, left)


# ------------------------------------------------------------------------------------------------
# a valid recording, and ways to spoil it


def base_recording(folder: Path) -> Path:
    """A small valid CSV run every reader accepts."""
    path = folder / "base.csv"
    if not path.exists():
        res = run_cli(["-q", "simulate", "--track", "circle_100", "--laps", "0.3", "--weave", "0.3", "-o", path], folder / "none")
        assert res.code == 0, f"the base recording could not be simulated: {res.stderr}"
    return path


def read_table(path: Path) -> tuple[list[str], np.ndarray]:
    rows = list(csv.reader(path.read_text().splitlines()))
    return rows[0], np.array(rows[1:], dtype=float)


def write_table(path: Path, header: list[str], data: np.ndarray, cells: dict[tuple[int, int], str] | None = None) -> Path:
    """``data`` as a CSV; ``cells`` replaces the text of (row from 0, column) cells."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for i, r in enumerate(data):
        w.writerow([(cells or {}).get((i, j), f"{v:.10g}") for j, v in enumerate(r)])
    path.write_text(buf.getvalue())
    return path


@dataclass
class Recording:
    """A spoilt copy of the base recording: ``make(base, folder, **params) -> path``."""

    name: str
    make: Callable[..., Path]
    expect: Callable[..., Refused | Excluded]
    params: dict = field(default_factory=dict)


def _cell(base: Path, folder: Path, row: int, column: str, text: str) -> Path:
    header, data = read_table(base)
    return write_table(folder / "bad.csv", header, data, {(row, header.index(column)): text})


def _scaled(base: Path, folder: Path, columns: tuple[str, ...], factor: float) -> Path:
    header, data = read_table(base)
    for c in columns:
        data[:, header.index(c)] *= factor
    return write_table(folder / "bad.csv", header, data)


def _time(base: Path, folder: Path, how: str, row: int) -> Path:
    header, data = read_table(base)
    t = data[:, header.index("t")]
    if how == "reversed":
        t[:] = t[::-1].copy()
    else:  # duplicated: sample ``row`` + 1 repeats the time of ``row``
        t[row + 1] = t[row]
    return write_table(folder / "bad.csv", header, data)


def _spin(base: Path, folder: Path, start: int, length: int = 31) -> Path:
    header, data = read_table(base)
    data[start:start + length, header.index("v_y")] = 15.0
    data[start:start + length, header.index("yaw_rate")] = 3.0
    return write_table(folder / "bad.csv", header, data)


def _truncated(base: Path, folder: Path, fields: int) -> Path:
    """The last row cut after ``fields`` of its values (a write that stopped mid-row)."""
    lines = base.read_text().splitlines()
    lines[-1] = ",".join(lines[-1].split(",")[:fields])
    p = folder / "bad.csv"
    p.write_text("\n".join(lines) + "\n")
    return p


def _dropped(base: Path, folder: Path, column: str) -> Path:
    header, data = read_table(base)
    j = header.index(column)
    return write_table(folder / "bad.csv", header[:j] + header[j + 1:], np.delete(data, j, axis=1))


def _bytes(folder: Path, blob: bytes, name: str = "bad.csv") -> Path:
    p = folder / name
    p.write_bytes(blob)
    return p


def _missing(folder: Path, name: str = "bad.csv") -> Path:
    return folder / "absent" / name


def _folder(folder: Path, name: str = "bad.csv") -> Path:
    p = folder / name
    p.mkdir()
    return p


def _rows_of(base: Path) -> int:
    return len(base.read_text().splitlines()) - 1


RECORDINGS = [
    Recording("missing", lambda b, f: _missing(f), lambda: Refused(("bad.csv", "no such file"))),
    Recording("empty", lambda b, f: _bytes(f, b""), lambda: Refused(("bad.csv", "empty"))),
    Recording("directory", lambda b, f: _folder(f), lambda: Refused(("bad.csv", "folder"))),
    Recording("garbage", lambda b, f, blob=b"\x89\xfe\x00garbage\xff": _bytes(f, blob), lambda **k: Refused(("bad.csv",)),
              {"blob": b"\x89\xfe\x00garbage\xff"}),
    Recording("truncated", _truncated, lambda fields=3: Refused(("bad.csv", "truncated")), {"fields": 3}),
    Recording("missing column", _dropped, lambda column="yaw_rate": Refused(("missing column", column)), {"column": "yaw_rate"}),
    Recording("NaN", lambda b, f, row=5, column="v_y": _cell(b, f, row, column, "nan"),
              lambda row=5, column="v_y": Refused((f"'{column}'", "non-finite", f"row {row + 1}")),
              {"row": 5, "column": "v_y"}),
    Recording("text", lambda b, f, row=5, column="e_y", word="abc": _cell(b, f, row, column, word),
              lambda row=5, column="e_y", word="abc": Refused((f"'{column}'", f"row {row + 1} (line {row + 2})", repr(word))),
              {"row": 5, "column": "e_y", "word": "abc"}),
    Recording("km/h (x3.6)", lambda b, f, columns=("v_x", "v_y"): _scaled(b, f, columns, 3.6),
              lambda columns=("v_x", "v_y"): Refused((f"'{columns[0]}'", "km/h")), {"columns": ("v_x", "v_y")}),
    Recording("deg/s (x57.3)", lambda b, f, columns=("yaw_rate",): _scaled(b, f, columns, 57.3),
              lambda columns=("yaw_rate",): Refused((f"'{columns[0]}'", "deg")), {"columns": ("yaw_rate",)}),
    Recording("degrees (x57.3)", lambda b, f, columns=("e_psi",): _scaled(b, f, columns, 57.3),
              lambda columns=("e_psi",): Refused((f"'{columns[0]}'", "deg")), {"columns": ("e_psi",)}),
    Recording("reversed time", lambda b, f: _time(b, f, "reversed", 0), lambda: Refused(("'t'", "not strictly increasing", "row 2"))),
    Recording("duplicated time", lambda b, f, row=10: _time(b, f, "duplicated", row),
              lambda row=10: Refused(("'t'", "not strictly increasing", f"row {row + 2}")), {"row": 10}),
]
SPIN = Recording("spin", _spin, lambda start=40: Excluded(("spin",)), {"start": 40})


# ------------------------------------------------------------------------------------------------
# config files and settings


def vehicle_file(folder: Path, old: str = "", new: str = "", extra: str = "") -> Path:
    """The shipped audi_tt_cup vehicle with ``old`` replaced by ``new`` and ``extra`` appended."""
    text = (configs_dir() / "vehicles" / "audi_tt_cup.toml").read_text()
    assert old in text
    p = folder / "car.toml"
    p.write_text(text.replace(old, new, 1) + extra)
    return p


def track_file(folder: Path, rows: list[str]) -> Path:
    p = folder / "track.csv"
    p.write_text("# x_m,y_m,w_tr_right_m,w_tr_left_m\n" + "".join(r + "\n" for r in rows))
    return p


SQUARE = ["0,0,5,5", "100,0,5,5", "100,80,5,5", "0,80,5,5"]


@dataclass
class Case:
    """One bad input given to one command: ``argv(folder, base) -> list`` (``{out}`` is
    ``folder / 'out'``, which must stay empty or absent)."""

    command: str
    kind: str
    argv: Callable[[Path, Path], list]
    expect: Refused | Excluded


def _out(folder: Path) -> Path:
    return folder / "out"


def recording_cases() -> list[Case]:
    """Every recording class given to every command that reads a recording (with the class's
    default parameters; the property tests vary them)."""
    cmds = {
        "show": lambda f, rec: ["show", rec],
        "select-data": lambda f, rec: ["select-data", rec, "--vehicle", "audi_tt_cup", "-o", _out(f) / "d.h5"],
        "diagnose": lambda f, rec: ["diagnose", rec, "--vehicle", "audi_tt_cup", "-o", _out(f) / "car.toml"],
    }
    out = []
    for cmd, argv in cmds.items():
        for r in RECORDINGS:
            if cmd == "show" and r.name.startswith(("km/h", "deg")):
                continue  # show describes a file as it is; units are checked by the stages that use them
            out.append(Case(cmd, r.name, lambda f, b, r=r, argv=argv: argv(f, r.make(b, f, **r.params)), r.expect(**r.params)))
    out.append(Case("select-data", SPIN.name, lambda f, b: ["select-data", SPIN.make(b, f, **SPIN.params), "--vehicle",
                                                            "audi_tt_cup", "--selection", "random", "-o", _out(f) / "d.h5"],
                    SPIN.expect(**SPIN.params)))
    return out


def config_cases() -> list[Case]:
    """Bad tracks, vehicles, plants, artifacts, names and numbers."""
    o = _out
    plan = lambda f, *a: ["plan", "--curvature", *a, "-o", o(f) / "p.h5"]  # noqa: E731
    C = Case
    return [
        # tracks
        C("track show", "missing", lambda f, b: ["track", "show", f / "none.csv"], Refused(("none.csv",))),
        C("track show", "unknown name", lambda f, b: ["track", "show", "monza_typo"], Refused(("monza_typo", "gprace_ring"))),
        C("track show", "empty", lambda f, b: ["track", "show", _bytes(f, b"", "t.csv")], Refused(("t.csv", "empty"))),
        C("track show", "garbage", lambda f, b: ["track", "show", _bytes(f, b"\x00\xff\x89", "t.csv")], Refused(("t.csv",))),
        C("track show", "directory", lambda f, b: ["track", "show", _folder(f, "t.csv")], Refused(("t.csv",))),
        C("plan", "track NaN", lambda f, b: plan(f, "--track", track_file(f, [SQUARE[0], "100,nan,5,5", *SQUARE[2:]])),
          Refused(("track.csv", "row 2 (line 3)", "y_m", "not finite"))),
        C("plan", "track text", lambda f, b: plan(f, "--track", track_file(f, [SQUARE[0], "100,0,five,5", *SQUARE[2:]])),
          Refused(("track.csv", "row 2 (line 3)", "w_tr_right_m", "'five'"))),
        C("plan", "track truncated", lambda f, b: plan(f, "--track", track_file(f, [*SQUARE, "0,40"])),
          Refused(("track.csv", "row 5 (line 6)", "truncated"))),
        C("plan", "track duplicated point", lambda f, b: plan(f, "--track", track_file(f, [SQUARE[0], *SQUARE])),
          Refused(("track.csv", "the same point twice"))),
        C("plan", "track too short", lambda f, b: plan(f, "--track", track_file(f, SQUARE[:3])), Refused(("track.csv", "at least 4"))),
        # vehicles
        C("plan", "vehicle unknown key", lambda f, b: plan(f, "--vehicle", vehicle_file(f, extra="\nspoiler = 3\n")),
          Refused(("car.toml", "spoiler"))),
        C("plan", "vehicle degrees (x57.3)", lambda f, b: plan(f, "--vehicle", vehicle_file(f, "steering_max = 0.35", "steering_max = 20.05")),
          Refused(("car.toml", "steering_max", "degrees"))),
        C("plan", "vehicle millimetres", lambda f, b: plan(f, "--vehicle", vehicle_file(f, "l_f = 1.0234", "l_f = 1023.4")),
          Refused(("car.toml", "l_f", "millimetres"))),
        C("plan", "vehicle text", lambda f, b: plan(f, "--vehicle", vehicle_file(f, "l_f = 1.0234", 'l_f = "long"')),
          Refused(("car.toml", "l_f"))),
        C("plan", "vehicle garbage", lambda f, b: plan(f, "--vehicle", _bytes(f, b"[[[\x00", "car.toml")), Refused(("car.toml",))),
        C("plan", "vehicle unknown name", lambda f, b: plan(f, "--vehicle", "audi_typo"), Refused(("audi_typo",))),
        C("diagnose", "vehicle directory", lambda f, b: ["diagnose", b, "--vehicle", _folder(f, "car.toml")],
          Refused(("car.toml", "folder"))),
        # plants
        C("simulate", "plant unknown name", lambda f, b: ["simulate", "--plant", "audi_typo", "-o", o(f) / "r.h5"], Refused(("audi_typo",))),
        C("simulate", "plant unknown kind", lambda f, b: ["simulate", "--plant", _bytes(f, b'kind = "bicycle"\nvehicle = "audi_tt_cup"\n', "plant.toml"),
                                                          "-o", o(f) / "r.h5"], Refused(("bicycle", "frenet"))),
        C("simulate", "plant unknown key", lambda f, b: ["simulate", "--plant", _bytes(f, b'kind = "frenet"\ngrip = 2\n', "plant.toml"),
                                                         "-o", o(f) / "r.h5"], Refused(("plant.toml", "grip"))),
        # artifacts
        C("run", "plan missing", lambda f, b: ["run", "--plan", f / "none.h5", "-o", o(f) / "r.h5"], Refused(("none.h5", "no such file"))),
        C("run", "plan garbage", lambda f, b: ["run", "--plan", _bytes(f, b"\x89HDF\r\n\x1a\nnot really", "p.h5"), "-o", o(f) / "r.h5"],
          Refused(("p.h5",))),
        C("run", "plan of the wrong kind", lambda f, b: ["run", "--plan", _as_h5(f, b), "-o", o(f) / "r.h5"], Refused(("run.h5", "plan"))),
        C("retrain", "dataset empty", lambda f, b: ["retrain", _bytes(f, b"", "d.h5"), "-o", o(f) / "m.h5"], Refused(("d.h5",))),
        C("retrain", "dataset of the wrong kind", lambda f, b: ["retrain", _as_h5(f, b), "-o", o(f) / "m.h5"], Refused(("run.h5", "dataset"))),
        C("retrain", "unknown option key", lambda f, b: ["retrain", _as_h5(f, b), "--opt", "jitter_magic=1", "-o", o(f) / "m.h5"],
          Refused(("jitter_magic", "available", "max_fit_points"))),
        C("import", "recording garbage", lambda f, b: ["import", _bytes(f, b"\x00\x01\x02", "log.csv"), "--track", "circle_100",
                                                       "-o", o(f) / "r.h5"], Refused(("log.csv",))),
        C("import", "recording text", lambda f, b: ["import", _bytes(f, b"time,x,y\n0,0,0\n0.1,abc,0\n", "log.csv"),
                                                    "--track", "circle_100", "-o", o(f) / "r.h5"], Refused(("log.csv", "row 2 (line 3)", "'abc'"))),
        C("import", "recording missing", lambda f, b: ["import", f / "none.csv", "--track", "circle_100", "-o", o(f) / "r.h5"],
          Refused(("none.csv",))),
        # names
        C("run", "unknown solver", lambda f, b: ["run", "--plan", f / "none.h5", "--solver", "gurobi", "-o", o(f) / "r.h5"],
          Refused(("gurobi", "clarabel"))),
        C("retrain", "unknown backend", lambda f, b: ["retrain", _as_h5(f, b), "--backend", "magic", "-o", o(f) / "m.h5"],
          Refused(("magic", "exact"))),
        C("select-data", "unknown feature map", lambda f, b: ["select-data", b, "--gp", "steering", "-o", o(f) / "d.h5"],
          Refused(("steering",))),
        C("eval head2head", "unknown GP backend", lambda f, b: ["eval", "head2head", "--gp-backend", "foo", "--out", o(f)],
          Refused(("foo", "exact"))),
        C("iterate", "unknown features", lambda f, b: ["iterate", "--features", "magic", "--out", o(f)], Refused(("magic",))),
        C("eval iterate", "not an iterate folder", lambda f, b: ["eval", "iterate", f], Refused(("settings.json",))),
    ]


def _as_h5(folder: Path, base: Path) -> Path:
    """The base recording as an HDF5 run (an artifact of the wrong kind for plan or dataset)."""
    p = folder / "run.h5"
    if not p.exists():
        from gprace.io.runs import read_run, write_run

        write_run(read_run(base), p)
    return p


# out-of-range numbers: (command words, option, valid-range test); the property tests draw values
# outside the range, the probe tries the given examples
NUMBERS = [
    (["plan", "--curvature"], "--grip", lambda v: 0 < v <= 1, (-0.5, 0.0, 1.5)),
    (["plan", "--curvature"], "--ds", lambda v: 0 < v <= 100, (-1.0, 0.0, 5000.0)),
    (["simulate"], "--weave", lambda v: 0 <= v <= 1, (-0.2, 1.5)),
    (["simulate"], "--laps", lambda v: v > 0, (0.0, -1.0)),
    (["run", "--plan", "{folder}/none.h5"], "--explore-radius", lambda v: v >= 0, (-1.0,)),
    (["run", "--plan", "{folder}/none.h5"], "--beta", lambda v: 0 < v < 1, (1.5, -0.1)),
    (["select-data", "{base}"], "--outlier-kappa", lambda v: v >= 0, (-1.0,)),
    (["h2h", "collect", "--out", "{folder}/out"], "--width", lambda v: v > 0, (0.0, -1.0)),
    (["eval", "head2head", "--out", "{folder}/out"], "--max-time", lambda v: v > 0, (-1.0, 0.0)),
]


def number_argv(words: list[str], option: str, value: float, folder: Path, base: Path) -> list:
    argv = [w.format(folder=folder, base=base) for w in words] + [option, repr(float(value))]
    if words[0] in ("plan", "simulate", "run", "select-data"):
        argv += ["-o", str(folder / "out" / "x.h5")]
    return argv


SETTING_NAMES: dict[str, str] = {}  # where a message names a setting otherwise than its option


def number_cases() -> list[Case]:
    return [Case(" ".join(w for w in words if not w.startswith(("{", "--"))), f"{option} {v:g}",
                 lambda f, b, words=words, option=option, v=v: number_argv(words, option, v, f, b),
                 Refused((SETTING_NAMES.get(option, option),)))
            for words, option, _, values in NUMBERS for v in values]


def all_cases() -> list[Case]:
    return recording_cases() + config_cases() + number_cases()


def variant_cases(rng: np.random.Generator, per_class: int = 3) -> list[Case]:
    """More cases of the recording classes and of the numbers, drawn with ``rng`` (other rows,
    columns, cut points, blobs, spins and values than the defaults; the probe's second pass)."""
    cols = ["t", "s", "e_y", "e_psi", "v_x", "v_y", "yaw_rate", "delta", "a_x", "kappa"]
    readers = {"show": lambda f, r: ["show", r],
               "select-data": lambda f, r: ["select-data", r, "--vehicle", "audi_tt_cup", "-o", _out(f) / "d.h5"],
               "diagnose": lambda f, r: ["diagnose", r, "--vehicle", "audi_tt_cup", "-o", _out(f) / "car.toml"]}
    units = [(("v_x",), 3.6, "km/h"), (("v_x", "v_y"), 3.6, "km/h"), (("yaw_rate",), 57.3, "deg"),
             (("e_psi",), 57.3, "deg"), (("delta",), 57.3, "deg")]
    out = []
    for cmd, argv in readers.items():
        for _ in range(per_class):
            row, col = int(rng.integers(0, 120)), str(rng.choice(cols))
            fields, blob = int(rng.integers(1, len(cols) + 2)), rng.bytes(int(rng.integers(1, 64)))
            cols_u, factor, unit = units[int(rng.integers(len(units)))]
            out += [
                Case(cmd, "NaN", lambda f, b, row=row, col=col, argv=argv: argv(f, _cell(b, f, row, col, "nan")),
                     Refused((f"column {col!r}", f"row {row + 1}"))),
                Case(cmd, "text", lambda f, b, row=row, col=col, argv=argv: argv(f, _cell(b, f, row, col, "x1")),
                     Refused((f"column {col!r}", f"row {row + 1} (line {row + 2})"))),
                Case(cmd, "truncated", lambda f, b, n=fields, argv=argv: argv(f, _truncated(b, f, n)), Refused(("truncated",))),
                Case(cmd, "duplicated time", lambda f, b, row=row, argv=argv: argv(f, _time(b, f, "duplicated", row)),
                     Refused(("'t'", f"row {row + 2}"))),
                Case(cmd, "garbage", lambda f, b, blob=blob, argv=argv: argv(f, _bytes(f, blob)), Refused(("bad.csv",))),
            ]
            if cmd != "show":
                out.append(Case(cmd, f"units x{factor:g}", lambda f, b, c=cols_u, k=factor, argv=argv: argv(f, _scaled(b, f, c, k)),
                                Refused((unit,))))
    for _ in range(per_class):
        start, length = int(rng.integers(0, 90)), int(rng.integers(12, 36))
        out.append(Case("select-data", "spin", lambda f, b, s=start, n=length: [
            "select-data", _spin(b, f, s, n), "--vehicle", "audi_tt_cup", "--selection", "random", "-o", _out(f) / "d.h5"],
            Excluded(("spin:",))))
    for words, option, valid, _ in NUMBERS:
        values = [v for v in rng.normal(0.0, 50.0, 40) if not valid(v)][:per_class]
        out += [Case(" ".join(w for w in words if not w.startswith(("{", "--"))), f"{option} {v:.3g}",
                     lambda f, b, words=words, option=option, v=v: number_argv(words, option, v, f, b),
                     Refused((SETTING_NAMES.get(option, option),))) for v in values]
    return out
