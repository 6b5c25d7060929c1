"""gprace: learning-based autonomous racing from the command line.

Stages live in one folder each (tracks, model, plants, sim, gp, ...); the CLI in
:mod:`gprace.cli` only parses, loads configuration, calls a stage and writes its artifact.
"""

__version__ = "0.1.0"
