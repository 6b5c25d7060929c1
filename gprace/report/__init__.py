"""Reports and figures (issue 7): look at any gprace result without writing code.

Public surface::

    from gprace.report import describe, build_report
    info = describe("run.h5")                 # summary dict of any artifact, CSV run or result JSON
    build_report("out/", "report.html", png_dir=None)   # one self-contained HTML page

Figures are small pure functions in :mod:`gprace.report.figures` (``fig_*(...) -> Figure``),
drawn with matplotlib's Agg canvas (no display, no global pyplot state). Heavy imports stay
inside functions so ``gprace --help`` stays fast.
"""

from gprace._lazy import lazy_face

# lazy: `gprace --help` imports this package
__all__, __getattr__ = lazy_face(__name__, {"inspect": "describe open_artifact", "html": "build_report"})
