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
    """Exit 2 and one ``error:`` line holding every needle, after the ``notes`` (warnings that
    must come first, e.g. a stale lock taken over); nothing left in the output folder."""

    needles: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()


@dataclass(frozen=True)
class Excluded:
    needles: tuple[str, ...] = ()


@dataclass(frozen=True)
class Accepted:
    """Exit 0 with every needle in stdout or stderr, none of ``absent`` in stdout, no error line
    and no warning but those holding one of ``notes``."""

    needles: tuple[str, ...] = ()
    absent: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()


@dataclass(frozen=True)
class Interrupted:
    """Ctrl-C or SIGTERM: exit 130, the last stderr line ``error: interrupted; ...`` holding every
    needle, no other error or warning line."""

    needles: tuple[str, ...] = ()


@dataclass(frozen=True)
class OneOf:
    """Any of several outcomes keeps the contract (the issue allows "read it, or a hint")."""

    options: tuple = ()


Expect = Refused | Excluded | Accepted | Interrupted | OneOf


@dataclass
class Outcome:
    code: int
    stderr: list[str]
    left_behind: list[str]
    stdout: str = ""
    extra: list[str] = field(default_factory=list)  # what a case's own check after the run found wrong
    signalled: bool = True  # False: the command had ended before the drawn moment of its interrupt

    @property
    def one_line(self) -> bool:
        return len(self.stderr) == 1

    @property
    def internal_error(self) -> bool:
        return any("internal error" in ln for ln in self.stderr)

    @property
    def traceback(self) -> bool:
        return any("Traceback" in ln for ln in self.stderr) or "Traceback" in self.stdout

    def problems(self, expect: Expect) -> list[str]:
        """What breaks the contract (empty when the command behaved)."""
        if isinstance(expect, OneOf):
            each = [self.problems(e) for e in expect.options]
            return [] if any(not b for b in each) else [" / ".join(b[0] for b in each if b)]
        if isinstance(expect, Interrupted) and not self.signalled:  # no signal was sent: a finished run
            return self.problems(Accepted(notes=("",)))
        bad = list(self.extra)
        notes = [ln for ln in self.stderr if ln.startswith(("error:", "warning:"))]
        if self.internal_error or self.traceback:
            bad.append("internal error or traceback")
        if isinstance(expect, Refused):
            lines = self.stderr[len(expect.notes):]
            if self.code != 2:
                bad.append(f"exit {self.code}, not 2")
            if len(lines) != 1 or not lines[0].startswith("error: "):
                bad.append(f"{len(self.stderr)} stderr lines, not {len(expect.notes)} note(s) and one error line")
            bad += [f"note {n!r} missing" for n, ln in zip(expect.notes, self.stderr + [""] * len(expect.notes))
                    if not (ln.startswith("warning: ") and n in ln)]
            if self.left_behind:
                bad.append(f"left behind: {self.left_behind}")
        elif isinstance(expect, Excluded):
            if self.code != 0:
                bad.append(f"exit {self.code}, not 0")
            if len(notes) != 1 or not notes[0].startswith("warning: ") or "outside the model's envelope" not in notes[0]:
                bad.append(f"not one exclusion note: {notes}")
        elif isinstance(expect, Accepted):
            if self.code != 0:
                bad.append(f"exit {self.code}, not 0: {notes[-1:] or self.stderr[-1:]}")
            bad += [f"unexpected {ln!r}" for ln in notes
                    if ln.startswith("error:") or not any(n in ln for n in expect.notes)]
            bad += [f"{a!r} in the output" for a in expect.absent if a in self.stdout]
            text = self.stdout + " ".join(self.stderr)
            return bad + [f"{n!r} not in the output" for n in expect.needles if n not in text]
        else:
            if self.code != 130:
                bad.append(f"exit {self.code}, not 130")
            if notes[-1:] != self.stderr[-1:] or len(notes) != 1 or not notes[0].startswith("error: interrupted; "):
                bad.append(f"not one interrupt line at the end: {notes}")
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
    return Outcome(code, lines, left, out.getvalue())


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
    expect: Expect
    run: Callable[[list, Path], Outcome] | None = None  # how to run it (default: run_cli in-process)
    after: Callable[[Path, Outcome], list[str]] | None = None  # what else must hold afterwards
    owner: str = "harden"  # who builds what the case asks for (issue 38: "ingest" for the reader rows)


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


def run_case(case: Case, folder: Path, base: Path) -> Outcome:
    """Run ``case`` in ``folder`` (its own way, or in-process) and apply its check afterwards."""
    argv = case.argv(folder, base)
    res = (case.run or run_cli)(argv, folder / "out")
    if case.after is not None:
        res.extra += case.after(folder, res)
    return res


# ------------------------------------------------------------------------------------------------
# issue 38: interrupts, sizes, output folders, verdicts, plausible vehicles, small contracts.
# Cases that run a subprocess (an interrupt, a second run beside a first) are in issue38_cases, not
# in all_cases: the tests have their own, shorter versions of them (test_interrupts, test_outputs).

import os  # noqa: E402 -- the section's own needs
import signal  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402

ENTRY = "import sys; from gprace.cli import main; sys.exit(main())"
TINY_ITERATE = ["iterate", "--iterations", "1", "--trials", "1", "--track", "circle_100", "--dictionary-size", "150"]
TINY_COLLECT = ["h2h", "collect", "--runs", "4", "--init-runs", "2", "--max-time", "2", "--workers", "1"]
TINY_H2H = ["eval", "head2head", "--tracks", "2", "--runs", "6", "--init-runs", "3", "--explore-minutes", "0.1",
            "--episode-seconds", "3", "--calib-runs", "1", "--calib-passes", "1", "--max-time", "3", "--samples", "5",
            "--points-per-run", "5", "--workers", "2"]


def _outcome(code: int, stderr: str, stdout: str, out_dir: Path) -> Outcome:
    left = sorted(p.name for p in out_dir.iterdir()) if out_dir.exists() else []
    return Outcome(code, [ln for ln in stderr.splitlines() if ln.strip()], left, stdout)


def _popen(argv: list, cwd: Path) -> subprocess.Popen:
    """A first run in its own session (its stdout dropped, its stderr read by :func:`_lines_until`)."""
    return subprocess.Popen([sys.executable, "-c", ENTRY, *map(str, argv)], cwd=cwd, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)


def _lines_until(p: subprocess.Popen, text: str, timeout: float = 600.0) -> tuple[list[str], threading.Event]:
    """Read ``p``'s stderr in a thread and wait until a line holds ``text`` (or stderr ends); the
    event returned is set when stderr has ended."""
    lines: list[str] = []
    seen, ended = threading.Event(), threading.Event()

    def read() -> None:
        for line in p.stderr:
            lines.append(line.rstrip("\n"))
            if text in line:
                seen.set()
        seen.set()
        ended.set()

    threading.Thread(target=read, daemon=True).start()
    seen.wait(timeout)
    return lines, ended


def interrupting(wait_for: str, delay: float, sig: int, group: bool) -> Callable[[list, Path], Outcome]:
    """Run the command in its own session; once a stderr line holds ``wait_for`` and ``delay``
    seconds more, send ``sig`` to its process group (Ctrl-C) or to it alone (``kill``)."""

    def run(argv: list, out_dir: Path) -> Outcome:
        stdout = out_dir.parent / "stdout.txt"
        with stdout.open("w") as fh:
            p = subprocess.Popen([sys.executable, "-c", ENTRY, *map(str, argv)], cwd=out_dir.parent, stdout=fh,
                                 stderr=subprocess.PIPE, text=True, start_new_session=True)
            lines, done = _lines_until(p, wait_for)
            time.sleep(delay)
            sent = p.poll() is None
            if sent:
                os.killpg(p.pid, sig) if group else p.send_signal(sig)
            try:
                p.wait(300)
            finally:
                if p.poll() is None:
                    os.killpg(p.pid, signal.SIGKILL)
        done.wait(30)  # the reader has taken every line once stderr closed
        res = _outcome(p.returncode, "\n".join(lines), stdout.read_text(), Path("/nonexistent"))
        res.signalled = sent
        return res

    return run


def beside_a_first_run(first: list, wait_for: str) -> Callable[[list, Path], Outcome]:
    """Start ``first`` (a real run into the same folder), and once it printed ``wait_for`` run the
    case's command beside it; the first is interrupted afterwards. The first is stopped
    (SIGSTOP, its lock held) while the second runs, so a short first run cannot end before the
    second looks at the folder (it did once in 280 cases on a loaded machine)."""

    def run(argv: list, out_dir: Path) -> Outcome:
        p = _popen(first, out_dir.parent)
        try:
            _lines_until(p, wait_for)
            if p.poll() is not None:
                return Outcome(-1, [f"probe: the first run ended before the second began (exit {p.returncode})"], [])
            os.killpg(p.pid, signal.SIGSTOP)
            r = subprocess.run([sys.executable, "-c", ENTRY, *map(str, argv)], cwd=out_dir.parent, capture_output=True,
                               text=True, timeout=1800)
        finally:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGCONT)
                os.killpg(p.pid, signal.SIGINT)
            try:
                p.wait(120)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
        return _outcome(r.returncode, r.stderr, r.stdout, Path("/nonexistent"))

    return run


def after_a_killed_run(first: list, wait_for: str) -> Callable[[list, Path], Outcome]:
    """Start ``first``, kill it (SIGKILL: no clean-up) once it printed ``wait_for``, then run the case."""

    def run(argv: list, out_dir: Path) -> Outcome:
        p = _popen(first, out_dir.parent)
        _lines_until(p, wait_for)
        os.killpg(p.pid, signal.SIGKILL)
        p.wait()
        return run_cli(argv, Path("/nonexistent"))

    return run


def read_only_folder(folder: Path) -> Path | None:
    """A folder no file can be made in (a read-only tmpfs as root, permissions otherwise); None
    where none can be made. Unmounted by :func:`release_read_only`."""
    ro = folder / "ro"
    ro.mkdir(exist_ok=True)
    if os.geteuid() != 0:
        ro.chmod(0o555)
        return ro
    ok = subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(ro)], capture_output=True).returncode == 0
    return ro if ok else None


def release_read_only(folder: Path) -> None:
    ro = folder / "ro"
    if ro.is_dir():
        if os.geteuid() == 0:
            subprocess.run(["umount", str(ro)], capture_output=True)
        else:
            ro.chmod(0o755)


def in_read_only(argv: list, out_dir: Path) -> Outcome:
    """Run in-process with ``out_dir.parent / 'ro'`` read-only (skipped, as kept, where none can be made)."""
    folder = out_dir.parent
    if read_only_folder(folder) is None:
        return Outcome(2, ["error: cannot write in (no read-only folder here: skipped)"], [])
    try:
        return run_cli(argv, out_dir)
    finally:
        release_read_only(folder)


def long_recording(folder: Path) -> Path:
    """A recording long enough for a diagnosis (1.5 laps of gprace_ring, weaving: diagnose and
    select-data run for some seconds after their first line, the span an interrupt is drawn in),
    made once per folder."""
    path = folder / "long.csv"
    if not path.exists():
        res = run_cli(["-q", "simulate", "--track", "gprace_ring", "--laps", "1.5", "--weave", "0.3", "-o", path],
                      folder / "none")
        assert res.code == 0, res.stderr
    return path


def _iterate_steps_consistent(folder: Path, res: Outcome) -> list[str]:
    """An interrupted iterate folder: no lock left, no oracle without its step, no step without its files."""
    out, bad = folder / "out", []
    if (out / ".gprace.lock").exists():
        bad.append("lock left behind")
    steps = {p.stem for p in (out / ".steps").glob("*.done")} if (out / ".steps").exists() else set()
    if ("oracle" in steps) != (out / "oracle.json").exists():
        bad.append("oracle.json and its step disagree")
    for st in steps:
        if st.endswith("_drive") and not (out / f"trial_{st.split('_')[0][1:]}" / f"iter_{int(st.split('_')[1][1:]):02d}"
                                           / "record.json").exists():
            bad.append(f"step {st} without its record")
    return bad


def _no_verdict(folder: Path, res: Outcome) -> list[str]:
    import json

    try:
        tab = json.loads(res.stdout)
    except ValueError:
        return ["no table printed"]
    return [f"claim {k}: {c['verdict']}" for k, c in tab.get("claims", {}).items() if c["verdict"] in ("holds", "fails")]


def _json_of(argv: list, folder: Path, name: str) -> Path:
    """The JSON that ``gprace -q argv --json`` prints, saved as ``folder/name`` (e.g. sim.json)."""
    res = run_cli(["-q", *argv, "--json"], folder / "none")
    assert res.code == 0, res.stderr
    p = folder / name
    p.write_text(res.stdout)
    return p


def _iterate_json(folder: Path, which: str) -> Path:
    """A JSON of an iterate folder, written by its real writer (settings.json, record.json)."""
    from gprace.timetrial.iterate import IterateSettings
    from gprace.timetrial.record import IterationRecord, write_json, write_record

    p = folder / which
    if which == "settings.json":
        write_json(p, IterateSettings(iterations=1, trials=1).model_dump(mode="json"))
    else:
        write_record(p, IterationRecord(iteration=1, trial=0, alpha=0.5, planned=50.0, driven=51.0, completed=True))
    return p


SHOWN = {  # file -> (how it is made, the kind show must name)
    "sim.json": (lambda f: _json_of(["simulate", "--track", "circle_100", "--laps", "0.2", "-o", f / "s.h5"], f, "sim.json"),
                 "simulate_result"),
    "plan.json": (lambda f: _json_of(["plan", "--curvature", "--track", "circle_100", "-o", f / "p.h5"], f, "plan.json"),
                  "plan_result"),
    "track.json": (lambda f: _json_of(["track", "show", "circle_100"], f, "track.json"), "track_show_result"),
    "settings.json": (lambda f: _iterate_json(f, "settings.json"), "iterate_settings"),
    "record.json": (lambda f: _iterate_json(f, "record.json"), "iteration_record"),
}

PLANTS_SHOWN = {"audi_nominal": "gprace_ring", "audi_hidden": "gprace_ring", "barc_nominal": "h2h_loop",
                "bmw_commonroad": "gprace_ring"}

IMPLAUSIBLE = [  # (what, shipped text, spoilt text, needle of the refusal)
    ("mu", "mu = 1.5", "mu = {v:.3g}", "tire-road friction", lambda r: float(10 ** r.uniform(0.55, 2))),
    ("mass in grams", "mass = 1161.25", "mass = {v:.6g}", "grams", lambda r: 1161.25 * 10 ** r.uniform(3, 4)),
    ("yaw inertia", "yaw_inertia = 2106.9543", "yaw_inertia = {v:.6g}", "half the car's diagonal",
     lambda r: 2106.95 * 10 ** r.uniform(2.5, 5)),
    ("wheelbase", "l_f = 1.0234", "l_f = {v:.4g}", "longer than the car's length", lambda r: r.uniform(2.8, 20)),
    ("CoG height", "cog_height = 0.5136", "cog_height = {v:.4g}", "above the car's width", lambda r: r.uniform(2.0, 10)),
]


def issue38_cases(rng: np.random.Generator, per_class: int = 3, expensive: int = 1) -> list[Case]:
    """Every row of issue 38's table that is not a reader's (those: :func:`ingest_cases`), as
    classes with ``per_class`` seeded variants each (``expensive`` for the classes that run whole
    commands: interrupts, two runs, the head-to-head table)."""
    o = _out
    C, out = Case, []
    draw = lambda k: range(per_class if k == "cheap" else expensive)  # noqa: E731
    # 1. interrupts: Ctrl-C (the whole process group) or SIGTERM (the command alone), at a drawn moment
    long = {
        "diagnose": (lambda f, b: ["diagnose", long_recording(b.parent), "--vehicle", "audi_tt_cup", "-o", o(f) / "car.toml"],
                     "diagnose:", None),
        "select-data": (lambda f, b: ["select-data", long_recording(b.parent), "--vehicle", "audi_tt_cup", "-o",
                                      o(f) / "d.h5"], "select-data:", None),
        "iterate": (lambda f, b: [*TINY_ITERATE, "--workers", "2", "--out", o(f)], "iteration 0", _iterate_steps_consistent),
        "eval head2head": (lambda f, b: [*TINY_H2H, "--out", o(f)], "runs to do", None),
    }
    for cmd, (argv, wait_for, after) in long.items():
        for _ in draw("expensive"):
            sig, group, delay = (signal.SIGINT, True, float(rng.uniform(0, 2))) if rng.random() < 0.6 else \
                (signal.SIGTERM, False, float(rng.uniform(0, 2)))
            out.append(C(cmd, f"{'Ctrl-C' if group else 'SIGTERM'} after {delay:.1f} s", argv, Interrupted(("interrupted",)),
                         run=interrupting(wait_for, delay, sig, group), after=after))
    # 2. sizes and numbers
    for _ in draw("cheap"):
        m = int(10 ** rng.uniform(5, 9))
        out.append(C("select-data", f"--max-points {m}", lambda f, b, m=m: [
            "select-data", b, "--vehicle", "audi_tt_cup", "--max-points", m, "-o", o(f) / "d.h5"],
            Accepted(("of at most",), notes=("outside the model's envelope",))))
        d = int(10 ** rng.uniform(6, 12))
        out.append(C("iterate", f"--dictionary-size {d}", lambda f, b, d=d: [*TINY_ITERATE, "--dictionary-size", d,
                                                                             "--out", o(f)],
                     Refused((f"--dictionary-size {d}", "points fit"))))
        small = int(rng.integers(-5, 10))
        out.append(C("iterate", f"--dictionary-size {small}", lambda f, b, d=small: [
            "iterate", "--dictionary-size", d, "--out", o(f)], Refused(("--dictionary-size must be >= 10",))))
        laps = str(rng.choice(["inf", "nan", "-inf", f"{10 ** rng.uniform(6, 15):.3g}"]))
        out.append(C("simulate", f"--laps {laps}", lambda f, b, v=laps: ["simulate", "--laps", v, "-o", o(f) / "r.h5"],
                     Refused(("--laps",))))
        dt = f"{10 ** rng.uniform(-14, -8):.2g}"
        out.append(C("simulate", f"--dt {dt}", lambda f, b, v=dt: ["simulate", "--dt", v, "-o", o(f) / "r.h5"],
                     Refused((f"--dt {dt}", "of memory"))))
        hz = int(rng.choice([0, 1, 2, 61, 1000, 10 ** 9]))
        out.append(C("diagnose", f"--horizon {hz}", lambda f, b, v=hz: ["diagnose", b, "--vehicle", "audi_tt_cup",
                                                                          "--horizon", v], Refused(("--horizon",))))
        ds = int(10 ** rng.uniform(6, 10))
        out.append(C("eval head2head", f"--dict-size {ds}", lambda f, b, v=ds: [*TINY_H2H, "--dict-size", v, "--out", o(f)],
                     Refused(("--dict-size", "points fit"))))  # tiny settings: what it costs where it is not checked
    # 3. output folders: read-only, in use by another run, left locked by a killed run
    unwritable = {
        "iterate": lambda f, b, sub: ["iterate", "--out", f / "ro" / sub],
        "simulate": lambda f, b, sub: ["simulate", "-o", f / "ro" / sub / "r.h5"],
        "import": lambda f, b, sub: ["import", b, "--track", "circle_100", "-o", f / "ro" / sub / "r.h5"],
        "report": lambda f, b, sub: ["report", f, "-o", f / "ro" / sub / "report.html"],
    }
    for cmd, argv in unwritable.items():
        for _ in draw("cheap"):
            sub = "/".join(f"d{int(rng.integers(100))}" for _ in range(int(rng.integers(0, 3)))) or "."
            out.append(C(cmd, "read-only folder", lambda f, b, a=argv, s=sub: a(f, b, s), Refused(("cannot write in",)),
                         run=in_read_only))
    for _ in draw("expensive"):
        out.append(C("iterate", "--out in use", lambda f, b: [*TINY_ITERATE, "--out", o(f)], Refused(("in use by pid",)),
                     run=beside_a_first_run([*TINY_ITERATE, "--workers", "1", "--out", "out"], "iteration 0")))
        out.append(C("h2h collect", "--out in use", lambda f, b: [*TINY_COLLECT, "--out", o(f)], Refused(("in use by pid",)),
                     run=beside_a_first_run([*TINY_COLLECT, "--out", "out"], "runs to do")))
        out.append(C("iterate", "lock of a killed run", lambda f, b: ["iterate", "--solver", "gurobi", "--out", o(f)],
                     Refused(("gurobi",), notes=("took over the lock",)),
                     run=after_a_killed_run([*TINY_ITERATE, "--workers", "1", "--out", "out"], "iteration 0")))
    # 4. verdicts from enough data
    for _ in draw("expensive"):
        out.append(C("eval head2head", "claims of 2 tracks", lambda f, b: ["-q", *TINY_H2H, "--json", "--out", o(f)],
                     Accepted(notes=("warning: ",)), after=_no_verdict))  # tiny fits and calibrations are warned
    # 5. implausible vehicles
    for what, old, new, needle, value in IMPLAUSIBLE:
        for _ in draw("cheap"):
            v = value(rng)
            out.append(C("plan", f"vehicle {what} {v:.3g}", lambda f, b, old=old, new=new, v=v: [
                "plan", "--curvature", "--vehicle", vehicle_file(f, old, new.format(v=v)), "-o", o(f) / "p.h5"],
                Refused(("car.toml", needle))))
    # 6. small contracts
    for name, (make, kind) in SHOWN.items():
        out.append(C("show", f"kind of {name}", lambda f, b, make=make: ["show", make(f)], Accepted((f"kind            {kind}",))))
    for _ in draw("cheap"):
        cmd = str(rng.choice(["select-data", "simulate", "track show", "show"]))
        argv = {"select-data": lambda f, b: ["select-data", b, "--vehicle", "audi_tt_cup", "--selection", "random",
                                             "-o", o(f) / "d.h5", "-q"],
                "simulate": lambda f, b: ["simulate", "--track", "circle_100", "--laps", "0.2", "-q", "-o", o(f) / "r.h5"],
                "track show": lambda f, b: ["track", "show", "-q", "circle_100"],
                "show": lambda f, b: ["show", b, "-q"]}[cmd]
        out.append(C(cmd, "-q after the subcommand", argv, Accepted(notes=("outside the model's envelope",))))
        plant = str(rng.choice(list(PLANTS_SHOWN)))
        out.append(C("simulate", f"plant {plant} named", lambda f, b, p=plant: [
            "simulate", "--plant", p, "--track", PLANTS_SHOWN[p], "--laps", "0.05", "-o", o(f) / "r.h5"],
            Accepted((f"plant {plant}",))))
    return out


# ------------------------------------------------------------------------------------------------
# issue 38's reader rows, owned by the ingest helper: they state what the issue asks; until the
# readers do it they fail, and the probe counts them apart (owner "ingest").


def global_log(base: Path, folder: Path, name: str = "log.csv", track: str = "circle_100") -> tuple[list[str], np.ndarray]:
    """The base recording in the global frame (what a car's logger writes): t, x, y, yaw, speeds,
    yaw rate, steering, acceleration."""
    from gprace.tracks import load_track

    header, data = read_table(base)
    col = {h: data[:, i] for i, h in enumerate(header)}
    tr = load_track(track)
    x, y = tr.to_global(col["s"], col["e_y"])
    yaw = tr.heading(col["s"]) + col["e_psi"]
    cols = ["t", "x", "y", "yaw", "v_x", "v_y", "yaw_rate", "delta", "a_x"]
    return cols, np.column_stack([col["t"], x, y, yaw, col["v_x"], col["v_y"], col["yaw_rate"], col["delta"], col["a_x"]])


def _log_text(base: Path, folder: Path, sep: str = ",", eol: str = "\n", bom: bool = False, t_scale: float = 1.0,
              zero: str | None = None) -> Path:
    cols, data = global_log(base, folder)
    data[:, 0] *= t_scale
    if zero is not None:
        data[:, cols.index(zero)] = 0.0
    lines = [sep.join(cols)] + [sep.join(f"{v:.10g}" for v in r) for r in data]
    p = folder / "log.csv"
    p.write_bytes(("\ufeff" if bom else "").encode() + eol.join(lines).encode() + eol.encode())
    return p


def _map_elsewhere(base: Path, folder: Path) -> Path:
    """A map naming its track file relative to the map's own folder (used from another folder)."""
    from gprace.tracks import load_track

    maps = folder / "maps"
    maps.mkdir(exist_ok=True)
    tr = load_track("circle_100")
    smp = tr.sample(2.0)
    rows = "\n".join(f"{x:.4f},{y:.4f},{wr:.3f},{wl:.3f}" for x, y, wr, wl in
                     zip(smp.x, smp.y, tr.width_right(smp.s), tr.width_left(smp.s)))
    (maps / "track.csv").write_text("# x_m,y_m,w_tr_right_m,w_tr_left_m\n" + rows + "\n")
    m = maps / "map.toml"
    m.write_text('track = "track.csv"\n')
    return m


def _s_continuous(folder: Path, res: Outcome) -> list[str]:
    """Without a track: s must not jump inside a lap (the issue: jumps over 100 m, 1,579 times)."""
    from gprace.io.runs import read_run

    p = folder / "out" / "r.h5"
    if res.code != 0 or not p.exists():
        return []
    run = read_run(p)
    ds = np.diff(run.data["s"])
    same_lap = np.diff(run.data["lap"]) == 0
    jumps = int(np.sum(np.abs(ds[same_lap]) > 20 * max(float(np.median(np.abs(ds))), 1e-3)))
    return [f"s jumps {jumps} times inside a lap"] if jumps else []


def ingest_cases(rng: np.random.Generator, per_class: int = 1) -> list[Case]:
    """The reader rows of issue 38 (BOM, CRLF and ';' files, ns/us time, map paths relative to
    the map, constant channels, a log of another track, s without a track), for the ingest helper."""
    o = _out
    cases = []
    for _ in range(per_class):
        cases += [
            Case("import", "UTF-8 BOM", lambda f, b: ["import", _log_text(b, f, bom=True), "--track", "circle_100",
                                                      "-o", o(f) / "r.h5"],
                 OneOf((Accepted(), Refused(("BOM",)))), owner="ingest"),
            Case("import", "CRLF", lambda f, b: ["import", _log_text(b, f, eol="\r\n"), "--track", "circle_100",
                                                 "-o", o(f) / "r.h5"], Accepted(), owner="ingest"),
            Case("import", "';'-separated", lambda f, b: ["import", _log_text(b, f, sep=";"), "--track", "circle_100",
                                                         "-o", o(f) / "r.h5"], OneOf((Accepted(), Refused(("';'",)))),
                 owner="ingest"),
            Case("import", "time in ns", lambda f, b: ["import", _log_text(b, f, t_scale=1e9), "--track", "circle_100",
                                                      "-o", o(f) / "r.h5"], Refused(('t = "ns"',)), owner="ingest"),
            Case("import", "time in us", lambda f, b: ["import", _log_text(b, f, t_scale=1e6), "--track", "circle_100",
                                                      "-o", o(f) / "r.h5"], Refused(('t = "us"',)), owner="ingest"),
            Case("import", "map path relative to the map", lambda f, b: [
                "import", _log_text(b, f), "--map", _map_elsewhere(b, f), "-o", o(f) / "r.h5"], Accepted(), owner="ingest"),
            Case("import", "a_x all zeros", lambda f, b: ["import", _log_text(b, f, zero="a_x"), "--track", "circle_100",
                                                         "-o", o(f) / "r.h5"],
                 Accepted(("a_x", "constant"), notes=("a_x",)), owner="ingest"),
            Case("import", "yaw_rate all zeros", lambda f, b: ["import", _log_text(b, f, zero="yaw_rate"), "--track",
                                                              "circle_100", "-o", o(f) / "r.h5"],
                 OneOf((Accepted(("yaw_rate", "constant"), notes=("yaw_rate",)), Refused(("yaw_rate",)))), owner="ingest"),
            Case("import", "log of another track", lambda f, b: ["import", _log_text(b, f), "--track", "gprace_ring",
                                                                "-o", o(f) / "r.h5"],
                 OneOf((Refused(("track",)), Accepted(("off the track",), notes=("off the track",)))), owner="ingest"),
            Case("import", "no track: s within a lap", lambda f, b: ["import", _log_text(b, f), "-o", o(f) / "r.h5"],
                 Accepted(notes=("reference line", "lap")), after=_s_continuous, owner="ingest"),
        ]
    return cases


# ------------------------------------------------------------------------------------------------
# the bad-input lines of issues 36 (real logs), 37 (time trial on unseen cars) and 39 (learn from
# files), probed from outside: each class with ``per_class`` seeded variants. Owners: "ingest"
# (the importer and track readers), "diagnose", "timetrial", "learn".

MAPPABLE = ("t", "x", "y", "yaw", "v_x", "v_y", "yaw_rate", "delta", "a_x")
RANGES = ("grip_front", "grip_rear", "downforce", "cog_height", "steering_lag", "relaxation_length", "yaw_inertia",
          "drag", "measurement_delay")


def _write_log(folder: Path, cols: list[str], data: np.ndarray, name: str = "log.csv") -> Path:
    p = folder / name
    p.write_text(",".join(cols) + "\n" + "".join(",".join(f"{v:.10g}" for v in r) + "\n" for r in data))
    return p


def _map_lacking(base: Path, folder: Path, quantity: str, name: str) -> tuple[Path, Path]:
    """The global log and a map that reads ``quantity`` from column ``name``, which the log lacks."""
    cols, data = global_log(base, folder)
    m = folder / "map.toml"
    m.write_text(f'[columns]\n{quantity} = "{name}"\n')
    return _write_log(folder, cols, data), m


def _clock_backwards(base: Path, folder: Path, row: int, back: float) -> Path:
    """The global log whose clock jumps back by ``back`` periods after sample ``row`` (from 0)."""
    cols, data = global_log(base, folder)
    dt = float(np.median(np.diff(data[:, 0])))
    data[row + 1:, 0] -= (1.0 + back) * dt
    return _write_log(folder, cols, data)


def _parked(base: Path, folder: Path, rng_seed: int, frenet: bool) -> Path:
    """A recording in which the car never moves (sensor noise only): a raw log, or a Frenet run."""
    r = np.random.default_rng(rng_seed)
    if frenet:
        header, data = read_table(base)
        col = {h: i for i, h in enumerate(header)}
        n = len(data)
        data[:, col["s"]] = 50.0 + 0.005 * r.standard_normal(n)
        for q, sd in (("v_x", 0.01), ("v_y", 0.01), ("yaw_rate", 0.001), ("a_x", 0.02), ("e_y", 0.002), ("e_psi", 0.001)):
            data[:, col[q]] = sd * r.standard_normal(n)
        return write_table(folder / "parked.csv", header, data)
    cols, data = global_log(base, folder)
    n = len(data)
    for q in ("x", "y", "yaw"):
        data[:, cols.index(q)] = data[0, cols.index(q)] + 0.002 * r.standard_normal(n)
    for q in ("v_x", "v_y", "yaw_rate", "a_x", "delta"):
        data[:, cols.index(q)] = 0.005 * r.standard_normal(n)
    return _write_log(folder, cols, data, "parked.csv")


def _crossing_bounds(folder: Path, start: float, span: float, push: float) -> str:
    """Both borders of circle_100 as headerless x, y files, the inner one pushed ``push`` widths
    outwards over ``span`` of the lap from ``start`` (shares of the lap): they cross there."""
    from gprace.tracks import load_track

    tr = load_track("circle_100")
    s = np.linspace(0.0, tr.length, 400, endpoint=False)
    wl, wr = tr.width_left(s), tr.width_right(s)
    d = np.mod(s / tr.length - start, 1.0)
    bump = np.where(d < span, np.sin(np.pi * d / span) ** 2, 0.0)
    lx, ly = tr.to_global(s, wl * (1.0 - (1.0 + push) * 2.0 * bump))
    rx, ry = tr.to_global(s, -wr)
    a, b = folder / "inner.csv", folder / "outer.csv"
    np.savetxt(a, np.column_stack([lx, ly]), delimiter=",", fmt="%.6f")
    np.savetxt(b, np.column_stack([rx, ry]), delimiter=",", fmt="%.6f")
    return f"{a},{b}"


def _randomized_plant(folder: Path, options: str) -> Path:
    p = folder / "plant.toml"
    p.write_text(f'kind = "randomized"\nvehicle = "audi_tt_cup"\n[options]\nseed = 3\n{options}\n')
    return p


def _raceline(folder: Path, fmt: str, spoil: str, pick: int) -> Path:
    """A raceline of circle_100 written by gprace's own writer in ``fmt``, its header spoilt: a
    column dropped, renamed or added (``pick`` chooses which)."""
    from gprace.config import load_vehicle
    from gprace.model import NominalModel
    from gprace.plan import curvature_plan
    from gprace.tracks import load_track
    from gprace.tracks.raceline import FORMATS, raceline_of_plan, write_raceline

    tr = load_track("circle_100")
    plan = curvature_plan(tr, NominalModel(load_vehicle("audi_tt_cup")), ds=5.0, speed_scale=0.7)
    p = write_raceline(folder / f"raceline_{fmt}.csv", raceline_of_plan(plan, tr), fmt)
    lines = p.read_text().splitlines()
    at = next(i for i, ln in enumerate(lines) if "s_m" in ln)
    sep = "; " if fmt == "tum" else ","
    names = lines[at].lstrip("# ").split(sep)
    free = [c for c in FORMATS[fmt] if c not in ("s_m", "x_m", "y_m")]
    victim = free[pick % len(free)]
    j = names.index(victim)
    if spoil == "dropped":
        names.pop(j)
        lines[at + 1:] = [sep.join(v for k, v in enumerate(ln.split(sep)) if k != j) for ln in lines[at + 1:]]
    elif spoil == "renamed":
        names[j] = victim.split("_")[0] + "_speed"
    else:  # an unexpected column added
        names.append("lap_count")
        lines[at + 1:] = [ln + sep + "1" for ln in lines[at + 1:]]
    lines[at] = ("# " if fmt == "tum" else "") + sep.join(names)
    p.write_text("\n".join(lines) + "\n")
    return p


def _others_learn_folder(folder: Path, vehicle: str, track: str = "circle_100") -> Path:
    """An --out folder holding learn iterations of ``vehicle`` (its identity, by learn's writer)."""
    from gprace.config import load_vehicle
    from gprace.learn.workflow import LearnSettings, car_identity, write_json
    from gprace.tracks import load_track

    theirs = folder / "theirs"
    theirs.mkdir(exist_ok=True)
    st = LearnSettings(track=track, vehicle=vehicle)
    write_json(theirs / "learn.json", car_identity(load_vehicle(vehicle), load_track(track), st))
    return theirs


def _iterate_folder(folder: Path) -> Path:
    theirs = folder / "theirs"
    theirs.mkdir(exist_ok=True)
    _iterate_json(theirs, "settings.json")
    return theirs


def _untouched(*names: str) -> Callable[[Path, Outcome], list[str]]:
    """After a refusal into another run's folder: it holds what it held (``names``), no lock."""

    def check(folder: Path, res: Outcome) -> list[str]:
        have = sorted(p.name for p in (folder / "theirs").iterdir())
        return [] if have == sorted(names) else [f"the other run's folder now holds {have}"]

    return check


def later_cases(rng: np.random.Generator, per_class: int = 3) -> list[Case]:
    """The bad-input lines of issues 36, 37 and 39 as classes with ``per_class`` seeded variants."""
    o, C, out = _out, Case, []
    for _ in range(per_class):
        # issue 36: a map naming a column the file lacks; a clock running backwards; boundary files
        # that cross; a recording with no moving sample
        q = str(rng.choice(MAPPABLE))
        name = f"{rng.choice(['gyro', 'Pos', 'chan', 'vel'])}_{int(rng.integers(100))}"

        def lacking(f, b, q=q, name=name):
            log, m = _map_lacking(b, f, q, name)
            return ["import", log, "--map", m, "--track", "circle_100", "-o", o(f) / "r.h5"]

        out.append(C("import", f"map names a column the file lacks ({q} = {name!r})", lacking,
                     Refused((f"'{name}'", "lacks")), owner="ingest"))
        row, back = int(rng.integers(3, 100)), float(rng.uniform(0.0, 20.0))
        out.append(C("import", f"clock running backwards after row {row + 1}", lambda f, b, row=row, back=back: [
            "import", _clock_backwards(b, f, row, back), "--track", "circle_100", "-o", o(f) / "r.h5"],
            Refused(("backwards", f"row {row + 2}")), owner="ingest"))
        start, span, push = float(rng.uniform(0, 1)), float(rng.uniform(0.05, 0.3)), float(rng.uniform(0.1, 1.0))
        cmd = str(rng.choice(["track show", "import", "plan"]))
        argv = {"track show": lambda f, b, t: ["track", "show", t],
                "import": lambda f, b, t: ["import", _log_text(b, f), "--track", t, "-o", o(f) / "r.h5"],
                "plan": lambda f, b, t: ["plan", "--curvature", "--track", t, "-o", o(f) / "p.h5"]}[cmd]
        out.append(C(cmd, "boundary files that cross", lambda f, b, a=argv, st=start, sp=span, pu=push: a(
            f, b, _crossing_bounds(f, st, sp, pu)), Refused(("cross",)), owner="ingest"))
        seed, frenet = int(rng.integers(1000)), bool(rng.random() < 0.5)
        out.append(C("diagnose" if frenet else "import", "no moving sample", (lambda f, b, s=seed: [
            "diagnose", _parked(b, f, s, True), "--vehicle", "audi_tt_cup", "-o", o(f) / "car.toml"]) if frenet else (
            lambda f, b, s=seed: ["import", _parked(b, f, s, False), "--track", "circle_100", "-o", o(f) / "r.h5"]),
            Refused(("no moving sample",)), owner="diagnose" if frenet else "ingest"))
        # issue 37: a randomized plant with an unknown key; a range upside down; a delay longer than
        # the MPC horizon
        key = f"{rng.choice(['grip', 'lag', 'aero', 'tyre'])}_{rng.choice(['max', 'rear', 'x'])}{int(rng.integers(10))}"
        cmd = str(rng.choice(["simulate", "iterate"]))
        go = {"simulate": lambda f, p: ["simulate", "--plant", p, "--laps", "0.05", "-o", o(f) / "r.h5"],
              "iterate": lambda f, p: ["iterate", "--plant", p, "--iterations", "1", "--trials", "1", "--out", o(f)]}[cmd]
        out.append(C(cmd, f"randomized plant unknown key {key}", lambda f, b, go=go, key=key: go(
            f, _randomized_plant(f, f"{key} = 1.0")), Refused(("plant.toml", key, "unknown key")), owner="timetrial"))
        rk = str(rng.choice(RANGES))
        lo = float(rng.uniform(0.05, 0.9))
        hi = lo + float(rng.uniform(0.01, 0.5))
        out.append(C(cmd, f"randomized plant range upside down ({rk})", lambda f, b, go=go, rk=rk, lo=lo, hi=hi: go(
            f, _randomized_plant(f, f"{rk} = [{hi:.3f}, {lo:.3f}]")), Refused(("plant.toml", rk, "upside down")),
            owner="timetrial"))
        delay = float(rng.uniform(1.05, 30.0))  # the default horizon: 20 x 0.05 s = 1 s
        how = str(rng.choice(["--delay", "vehicle measurement_delay", "vehicle actuator_delay"]))
        if how == "--delay":
            argv = lambda f, b, d=delay: ["iterate", "--delay", f"{d:.3f}", "--out", o(f)]  # noqa: E731
        else:
            field_ = how.split()[1]
            argv = lambda f, b, d=delay, k=field_: ["iterate", "--vehicle", vehicle_file(  # noqa: E731
                f, "mu = 1.5", f"mu = 1.5\n{k} = {d:.3f}"), "--out", o(f)]
        out.append(C("iterate", f"delay {delay:.2f} s beyond the horizon ({how})", argv,
                     Refused(("longer than the MPC horizon",)), owner="timetrial"))
        # issue 39: recordings of different tracks to learn; a raceline whose columns do not match
        # its format; an --out folder holding another car's iterations
        shift = float(rng.uniform(150.0, 2000.0)) * np.exp(1j * rng.uniform(0, 2 * np.pi))
        first_other = bool(rng.random() < 0.5)

        def different(f, b, shift=shift, first_other=first_other):
            cols, data = global_log(b, f)
            data[:, 1] += shift.real
            data[:, 2] += shift.imag
            mine, other = _log_text(b, f), _write_log(f, cols, data, "far.csv")
            recs = [other, mine] if first_other else [mine, other]
            return ["learn", *recs, "--track", "circle_100", "--vehicle", "audi_tt_cup", "--out", o(f)]

        out.append(C("learn", f"recordings of different tracks (moved {abs(shift):.0f} m)", different,
                     Refused(("recordings of different tracks",)), owner="learn"))
        fmt, spoil, pick = str(rng.choice(["tum", "f1tenth"])), str(rng.choice(["dropped", "renamed", "added"])), \
            int(rng.integers(100))
        cmd = str(rng.choice(["track show", "run", "plan"]))
        argv = {"track show": lambda f, r: ["track", "show", r],
                "run": lambda f, r: ["run", "--plan", r, "--track", "circle_100", "-o", o(f) / "r.h5"],
                "plan": lambda f, r: ["plan", "--warm-start", r, "--track", "circle_100", "-o", o(f) / "p.h5"]}[cmd]
        out.append(C(cmd, f"{fmt} raceline, a column {spoil}", lambda f, b, a=argv, fmt=fmt, sp=spoil, pk=pick: a(
            f, _raceline(f, fmt, sp, pk)), Refused(("columns do not match", f"{fmt} raceline")), owner="learn"))
        other = str(rng.choice(["barc_1_10", "bmw_320i"]))
        out.append(C("learn", f"--out holds the iterations of {other}", lambda f, b, v=other: [
            "learn", b, "--track", "circle_100", "--vehicle", "audi_tt_cup", "--out", _others_learn_folder(f, v)],
            Refused(("--out", f"iterations of car {other!r}")), after=_untouched("learn.json"), owner="learn"))
    # gprace runs (Frenet CSV) of two tracks: once (while it is accepted it runs a whole learn)
    first_other = bool(rng.random() < 0.5)
    out.append(C("learn", "runs of different tracks", lambda f, b, first_other=first_other: [
        "learn", *([long_recording(b.parent), b] if first_other else [b, long_recording(b.parent)]),
        "--track", "circle_100", "--vehicle", "audi_tt_cup", "--out", o(f)],
        Refused(("recordings of different tracks",)), owner="learn"))
    out.append(C("learn", "--out holds an iterate experiment", lambda f, b: [
        "learn", b, "--track", "circle_100", "--vehicle", "audi_tt_cup", "--out", _iterate_folder(f)],
        Refused(("--out", "iterate experiment")), after=_untouched("settings.json"), owner="learn"))
    return out
