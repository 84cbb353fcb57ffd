"""Solver-comparison benchmark (``ltv-lstm-mpc bench`` / ``replay``), outside the controller core.

Modules
-------
harness
    Backends x horizons x scenarios, each run through
    :func:`~ltv_lstm_mpc.simulate`.
"""
