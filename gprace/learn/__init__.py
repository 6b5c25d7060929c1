"""``gprace learn``: the paper's step between two iterations, done from recorded laps.

A team runs the iterative double-GP loop on a real car through files: the car drives laps with its
own stack, the logs come off the car, ``gprace learn`` retrains both GPs and re-plans the lap, and
the raceline goes back onto the car (:mod:`gprace.tracks.raceline`). ``gprace eval learn``
compares the prediction with the next recorded lap.

- :mod:`gprace.learn.workflow`: the stages (import, select, retrain, plan, export, predict), the
  folder, resuming and provenance;
- :mod:`gprace.learn.predict`: the prediction a lap is held to (the GP's band along the lap, the
  places where the plan uses most of the learned grip), its comparison with a recorded lap, and
  one- and multi-step prediction errors of the nominal and the learned model.
"""

from gprace._lazy import lazy_face

__all__, __getattr__ = lazy_face(__name__, {
    "workflow": "LearnSettings learn", "predict": "evaluate_learn prediction_errors"})
