"""Benchmarks beyond the paper's own (Section V), each on its true plant.

Modules
-------
quadtank
    The quadruple-tank process (two pumps, two levels) with the shipped (2, 2) LSTM:
    set-point changes on both levels and a leak disturbance, on the condensed and the
    exact-cone solver paths (``ltv-lstm-mpc reproduce --benchmark quadtank``).
"""
