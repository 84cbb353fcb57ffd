"""Identification data and delta-ISS training of the LSTM (torch only here).

Modules
-------
datasets
    Multilevel pseudo-random identification experiments on the pH plant.
train
    Training with the paper's loss and the delta-ISS penalty (needs the ``train`` extra).
cli
    ``ltv-lstm-mpc generate-data`` and ``ltv-lstm-mpc train``.
"""
