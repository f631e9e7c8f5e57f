"""Experiments on real processes, run on the emulated team (``ramps.testbed``).

Each module here is a scenario that makes a fresh ``Testbed`` of real
``ramps node`` processes, runs a workload on it, and reports figures: two
sites behind routers (``sites``), a slow link (``slowlink``), many robots
lost at once (``mass_loss``). ``ramps testbed experiment NAME`` runs them
(root); ``python -m ramps.lab.mass_loss`` runs the one that has no command.
"""
