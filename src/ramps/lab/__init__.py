"""Experiments on real processes, run on the emulated team (``ramps.testbed``).

Each module here is a scenario that makes a fresh ``Testbed`` of real
``ramps node`` processes, runs a workload on it, and reports figures, often
beside the simulator's for the same set-up (``ramps.experiments`` and
``ramps.sim``): the paper's failure experiments (``experiments``, which also
holds what the experiments share), its sweeps and several-origins bursts
(``sweeps``), a randomized fault campaign (``campaign``), ramps beside round
robin, Ray and Dask (``peers``), relocation (``late_load``), restarts
(``restart``), batteries, accelerators, slow links, two sites, how alike
identical robots measure themselves (``speeds``), how closely a robot
follows processor sharing (``fidelity``), and how fast faults are noticed
(``detect``).

``ramps testbed experiment NAME``, ``ramps testbed campaign`` and ``ramps
testbed fidelity`` run them (root); ``python -m ramps.lab.detect`` and
``python -m ramps.lab.mass_loss`` run the two measurements that have no
command.
"""
