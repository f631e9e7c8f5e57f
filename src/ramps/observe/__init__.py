"""Seeing the team from outside the core: reports and figures of runs
(``report``, ``plots``) and a live terminal view (``top``). Nothing here takes
a decision; everything reads the actions the core emits, its
``statistics()``, load reports and traces. A node's Prometheus metrics are
served by the node itself (``ramps.runtime.metrics``)."""
