"""The paper's five closed-loop simulations (Section V) and ``ltv-lstm-mpc reproduce``.

Modules
-------
scenarios
    The scenarios as data (plant, set-points, disturbances, configuration).
reproduce
    Runs them and writes plots, CSV and a summary.
"""
