"""The console wrapper: tables written to pipes and files keep every cell whole."""

from __future__ import annotations

from gprace.console import Console


def test_table_off_terminal_is_not_truncated(capsys):
    header = [f"column number {i}" for i in range(8)]  # about 150 characters wide
    cells = [f"value {i} +- 0.123" for i in range(8)]
    Console().table("wide", header, [cells])
    out = capsys.readouterr().out
    for text in header + cells:
        assert text in out
