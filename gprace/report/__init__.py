"""Reports and figures (issue 7): look at any gprace result without writing code.

Public surface::

    from gprace.report import describe, build_report
    info = describe("run.h5")                 # summary dict of any artifact, CSV run or result JSON
    build_report("out/", "report.html", png_dir=None)   # one self-contained HTML page

Figures are small pure functions in :mod:`gprace.report.figures` (``fig_*(...) -> Figure``),
drawn with matplotlib's Agg canvas (no display, no global pyplot state). Heavy imports stay
inside functions so ``gprace --help`` stays fast.
"""

__all__ = ["build_report", "describe", "open_artifact"]


def __getattr__(name: str):
    # lazy: `gprace --help` imports the commands module of this package, which must stay light
    if name in ("describe", "open_artifact"):
        from gprace.report import inspect

        return getattr(inspect, name)
    if name == "build_report":
        from gprace.report.html import build_report

        return build_report
    raise AttributeError(name)
