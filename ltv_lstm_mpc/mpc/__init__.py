"""The robust MPC of eq. (optimization): configuration, FHOCP transcriptions, RTI, NMPC.

Import the names from the modules (or from :mod:`ltv_lstm_mpc`).
"""
