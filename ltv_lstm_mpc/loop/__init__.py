"""The closed loop of the paper's Fig. 1, one module per block.

Modules
-------
observer
    :class:`Observer`, eq. (lstm_observer) with the disturbance estimate.
reference
    :class:`ReferenceCalculator`, eq. (reference_calculation), and :math:`\\bar K` (Lemma 5).
controller
    :class:`OffsetFreeController`: normalization -> observer -> reference -> MPC ->
    de-normalization, one ``step`` per sample.
simulation
    :func:`simulate`: plant and controller in closed loop.

Import the names from these modules (or from :mod:`ltv_lstm_mpc`).
"""
