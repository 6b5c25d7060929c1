"""``gprace diagnose``: locate the sim-to-real mismatch, name the missing physics, model it, show it.

Modules: :mod:`~gprace.diagnose.core` (recordings -> batched multi-step predictions, noise twin),
:mod:`~gprace.diagnose.locate` (structured vs noise, regions along the track, regime),
:mod:`~gprace.diagnose.name` (bounded fits of catalogue effects, cross-validated forward
selection, ambiguity, intervals), :mod:`~gprace.diagnose.diagnose` (the pipeline and the JSON
report), :mod:`~gprace.diagnose.report` (text, augmented vehicle TOML, plot) and
:mod:`~gprace.diagnose.synth` (concealed-effect recordings for tests and the benchmark).
"""
