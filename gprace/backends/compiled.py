"""Moved to :mod:`gprace.compiled` (the core layer: the GP kernel, the tracking MPC, the diagnosis
and the head-to-head NMPC all compile code through it, and a component must not reach into the
backends for it; issue 40). These names stay importable from here, as before."""

from gprace.compiled import (  # noqa: F401
    FLAGS,
    cache_dir,
    compiled_function,
    compiled_nlpsol,
    compiled_source,
    compiler,
)
