"""``gprace diagnose``: locate the sim-to-real mismatch, name the missing physics, model it, show it.

Modules: :mod:`~gprace.diagnose.core` (recordings -> batched multi-step predictions, noise twin),
:mod:`~gprace.diagnose.locate` (structured vs noise, regions along the track, regime),
:mod:`~gprace.diagnose.name` (bounded fits of catalogue effects, cross-validated forward
selection, ambiguity, intervals), :mod:`~gprace.diagnose.diagnose` (the pipeline and the JSON
report; the function is ``gprace.diagnose.diagnose.diagnose``), :mod:`~gprace.diagnose.result` (the
result's schema: ``DiagnosisResult``, versioned, read through ``read_result`` / ``parse_result``),
:mod:`~gprace.diagnose.report` (text, augmented vehicle TOML, plot) and
:mod:`~gprace.diagnose.synth` (concealed-effect recordings for tests and the benchmark).

Public surface::

    from gprace.diagnose import Diagnosis, DiagnosisResult, read_result, summary_lines, write_augmented, record
"""

from gprace._lazy import lazy_face

__all__, __getattr__ = lazy_face(__name__, {
    "diagnose": "Diagnosis", "result": "DiagnosisResult read_result parse_result",
    "report": "write_augmented summary_lines", "synth": "record"})
