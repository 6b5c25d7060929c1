"""One module per section of the report; each turns a :class:`~gprace.report.collect.Found` into a
:class:`~gprace.report.collect.Section`."""
