"""Seeing the team from outside the core: Prometheus metrics of a node
(``metrics``), reports and figures of runs (``report``, ``plots``) and a live
terminal view (``top``). Nothing here takes a decision; everything reads the
actions the core emits, its ``statistics()``, load reports and traces."""
