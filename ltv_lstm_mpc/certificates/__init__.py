"""Certificates of the paper: what makes the robust MPC's guarantees hold.

Modules
-------
stability
    delta-ISS (Assumption 2, Theorem 1, Remark 1), the incremental Lyapunov function
    (Lemma 2) and the observer (Assumption 3, Lemma 4, Theorem 2, gain design paper notes 2.11).
tightening
    The constraint tightening a_i, b_i, e_inf, the terminal weight P_f and level alpha_k,
    the admissible set-point interval (Assumption 5) and Theorem 3's set-point rate bound.
certify
    :func:`certify`: every certificate of a model, in the paper's order.

Import the names from these modules (or from :mod:`ltv_lstm_mpc`).
"""
