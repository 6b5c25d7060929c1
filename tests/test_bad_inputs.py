"""Issue 16: every command, every class of bad input (``bad_inputs.py``), in-process.

A refused input exits 2 with exactly one ``error:`` line naming the file, column, row or setting,
and leaves nothing behind; recoverable data (a spin) is used without it and says so in the one
documented exclusion note. The sweep tries each case once; the properties (hypothesis) vary where
and how the data is spoilt, and the numbers and names given.
"""

from __future__ import annotations

import string
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import bad_inputs as B

SMALL = settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
COLUMNS = ["t", "s", "e_y", "e_psi", "v_x", "v_y", "yaw_rate", "delta", "a_x", "kappa"]


@pytest.fixture(autouse=True)
def _no_debug(monkeypatch):
    monkeypatch.delenv("GPRACE_DEBUG", raising=False)


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    return B.base_recording(tmp_path_factory.mktemp("bad_inputs"))


def check(argv_of, base: Path, expect) -> None:
    """Run ``argv_of(folder)`` in a fresh folder and assert the contract."""
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        out = B.run_cli(argv_of(folder), folder / "out")
        assert not out.problems(expect), (out.problems(expect), out.stderr)


CASES = B.all_cases()


@pytest.mark.parametrize("case", CASES, ids=[f"{c.command}: {c.kind}" for c in CASES])
def test_every_command_refuses_every_class_once(case, base):
    check(lambda f: case.argv(f, base), base, case.expect)


def test_the_sweep_covers_every_class_of_the_issue():
    kinds = " ".join(c.kind for c in CASES)
    for k in ("missing", "empty", "directory", "garbage", "truncated", "NaN", "text", "x3.6", "x57.3", "spin",
              "reversed time", "duplicated time", "unknown key", "unknown name", "--grip"):
        assert k in kinds, k
    assert len({c.command for c in CASES}) >= 12


# ------------------------------------------------------------------------------------------------
# properties: where and how a recording is spoilt

READERS = st.sampled_from(["show", "select-data", "diagnose"])


def reader_argv(cmd: str, rec: Path, folder: Path) -> list:
    return {"show": ["show", rec],
            "select-data": ["select-data", rec, "--vehicle", "audi_tt_cup", "-o", folder / "out" / "d.h5"],
            "diagnose": ["diagnose", rec, "--vehicle", "audi_tt_cup", "-o", folder / "out" / "car.toml"]}[cmd]


@SMALL
@given(cmd=READERS, row=st.integers(0, 120), column=st.sampled_from(COLUMNS),
       value=st.sampled_from(["nan", "NaN", "inf", "-inf"]))
def test_a_non_finite_cell_is_named_by_column_and_row(base, cmd, row, column, value):
    check(lambda f: reader_argv(cmd, B._cell(base, f, row, column, value), f), base,
          B.Refused((f"column {column!r}", "non-finite", f"row {row + 1}")))


@SMALL
@given(cmd=READERS, row=st.integers(0, 120), column=st.sampled_from(COLUMNS),
       word=st.text(string.ascii_letters, min_size=1, max_size=6).filter(lambda w: w.lower() not in ("nan", "inf", "infinity")))
def test_a_text_cell_is_named_by_column_row_and_line(base, cmd, row, column, word):
    check(lambda f: reader_argv(cmd, B._cell(base, f, row, column, word), f), base,
          B.Refused((f"column {column!r}", f"row {row + 1} (line {row + 2})", repr(word))))


@SMALL
@given(cmd=READERS, fields=st.integers(1, len(COLUMNS) + 1))
def test_a_row_cut_short_is_a_truncated_file(base, cmd, fields):
    check(lambda f: reader_argv(cmd, B._truncated(base, f, fields), f), base, B.Refused(("truncated", "row 127 (line 128)")))


@SMALL
@given(cmd=st.sampled_from(["select-data", "diagnose"]),
       units=st.sampled_from([(("v_x",), 3.6, "km/h"), (("v_x", "v_y"), 3.6, "km/h"), (("yaw_rate",), 57.3, "deg"),
                              (("e_psi",), 57.3, "deg"), (("delta",), 57.3, "deg"), (("yaw_rate", "delta"), 57.3, "deg")]))
def test_wrong_units_name_the_column_and_the_probable_unit(base, cmd, units):
    columns, factor, unit = units
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        out = B.run_cli(reader_argv(cmd, B._scaled(base, folder, columns, factor), folder), folder / "out")
        assert not out.problems(B.Refused((unit,))), out.stderr
        assert any(f"column {c!r}" in out.stderr[0] for c in columns), out.stderr


@SMALL
@given(cmd=READERS, row=st.integers(0, 120))
def test_time_that_stands_still_or_runs_back_names_the_row(base, cmd, row):
    check(lambda f: reader_argv(cmd, B._time(base, f, "duplicated", row), f), base,
          B.Refused(("column 't' is not strictly increasing", f"row {row + 2}")))


@SMALL
@given(cmd=READERS, blob=st.binary(min_size=1, max_size=64))
def test_garbage_is_one_line(base, cmd, blob):
    check(lambda f: reader_argv(cmd, B._bytes(f, blob), f), base, B.Refused(("bad.csv",)))


@SMALL
@given(start=st.integers(0, 90), length=st.integers(12, 36))
def test_a_spin_is_left_out_and_said_where(base, start, length):
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        rec = B._spin(base, folder, start, length)
        out = B.run_cli(["select-data", rec, "--vehicle", "audi_tt_cup", "--selection", "random", "-o",
                         folder / "out" / "d.h5"], folder / "out")
        assert not out.problems(B.Excluded(("spin:",))), out.stderr
        note = next(ln for ln in out.stderr if ln.startswith("warning:"))
        excluded = int(note.split("excluded ")[1].split(" of")[0])
        assert excluded >= length, note


# ------------------------------------------------------------------------------------------------
# properties: numbers out of range and names that do not exist


@st.composite
def out_of_range(draw):
    words, option, valid, _ = draw(st.sampled_from(B.NUMBERS))
    value = draw(st.floats(-1e4, 1e4, allow_nan=False).filter(lambda v: not valid(v)))
    return words, option, value


@SMALL
@given(case=out_of_range())
def test_a_number_out_of_range_is_refused_naming_the_setting(base, case):
    words, option, value = case
    check(lambda f: B.number_argv(words, option, value, f, base), base, B.Refused((B.SETTING_NAMES.get(option, option),)))


NAMES = [
    (lambda n, f: ["plan", "--curvature", "--track", n, "-o", f / "out" / "p.h5"], "circle_100"),
    (lambda n, f: ["plan", "--curvature", "--vehicle", n, "-o", f / "out" / "p.h5"], "audi_tt_cup"),
    (lambda n, f: ["simulate", "--plant", n, "-o", f / "out" / "r.h5"], "audi_nominal"),
    (lambda n, f: ["run", "--plan", f / "none.h5", "--solver", n, "-o", f / "out" / "r.h5"], "clarabel"),
    (lambda n, f: ["eval", "head2head", "--gp-backend", n, "--out", f / "out"], "exact"),
    (lambda n, f: ["iterate", "--features", n, "--out", f / "out"], "paper"),
]


@SMALL
@given(which=st.sampled_from(NAMES), name=st.text(string.ascii_lowercase + "_", min_size=3, max_size=10))
def test_an_unknown_name_is_refused_and_the_valid_ones_listed(base, which, name):
    argv, valid = which
    if name in ("auto", "sparse", "full", "paper", "casadi", "clarabel"):
        return  # a valid name
    check(lambda f: argv(name, f), base, B.Refused((name, valid)))
