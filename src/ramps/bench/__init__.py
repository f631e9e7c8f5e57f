"""Robustness and speed benchmarks: each prints its figures and saves JSON.

How this works: a benchmark measures, it never asserts (the tests do); each
returns a plain dict that the CLI (``ramps bench ...``, ``ramps.cli.bench``)
prints and writes to a JSON file, with the machine it ran on. The paper's
experiments in the simulator live in ``ramps.experiments``; these are ours:

* ``demo``: the paper's scenario on a real team on this machine, placed by
  ramps, by round robin and on one robot, with an HTML report (``ramps
  demo``, the main job; it returns a ``DemoReport``);
* ``simulator``: the simulator's speed (``ramps bench sim``: paper sweeps, a
  1000-robot team) and ``machine()``, the host every benchmark records;
* ``dispatch``: submit-to-result latency and throughput on a real loopback
  team (``ramps bench dispatch``);
* ``dispatchcpu``: the CPU one program costs in the core alone, and in the
  drivers, core and client without the network
  (``python -m ramps.bench.dispatchcpu``); ``dispatchstages``: where one
  call's time goes, stage by stage, from the nodes' traces
  (``python -m ramps.bench.dispatchstages``);
* ``fuzz``: hostile input (``ramps.testing.hostile``) at the decoders and the
  core (``ramps bench fuzz``);
* ``flood``: a real node flooded with malformed messages keeps working
  (``ramps bench flood``);
* ``metrics_cost``: what serving Prometheus metrics costs an idle node,
  and the CPU of one ``/metrics`` render (``ramps bench metrics``);
* ``progbench``: what executables, progress and the ROS face cost
  (``python -m ramps.bench.progbench``);
* ``teamsize``: what each robot of a team of N real nodes costs, a burst
  and a fifth of the robots killed (``ramps bench team-size``);
* ``workerstart``: how soon programs beyond one per core start
  (``python -m ramps.bench.workerstart``).
"""
