"""Solver-comparison benchmark (``ltv-lstm-mpc bench`` / ``replay``), outside the controller core.

Modules
-------
harness
    Backends x horizons x scenarios, each run through
    :func:`~ltv_lstm_mpc.simulate`.
qpbenchmark_set
    The subproblems solved along closed loops as a qpbenchmark test set (``bench
    --export-qpbenchmark``), and qpbenchmark's metrics from this library's solver layer
    (``bench --qpbenchmark-set``).
"""
