"""Benchmarks of the engine: the work-precision study and the speed benchmark (``mps bench``).

* :mod:`~mps_core.bench.common`: the cases (``paper`` over 0.1 s, ``paper-long`` over 1 s,
  ``press-cycle``), the references, timed runs;
* :mod:`~mps_core.bench.peers`: the peer, scipy's DOP853 on exact equations derived with sympy
  (also the reference where it applies);
* :mod:`~mps_core.bench.accuracy`: error against the reference vs CPU time, per solver, step
  size or tolerance, and derivative scheme; the round-off floor of central differences;
* :mod:`~mps_core.bench.speed`: CPU per step and real-time factor at 1 kHz, engine and solver
  alone, one evaluation, each effect;
* :mod:`~mps_core.bench.cli`: the ``mps bench`` subcommands.

sympy and matplotlib come with the ``bench`` extra (``pip install -e '.[bench]'``).
"""
