"""Shared pytest configuration."""

from __future__ import annotations

import os

from hypothesis import HealthCheck, settings

# The suite runs the compiled kernels, compiling in-process where numba's cache lacks them
# (the default "auto" would run numpy there and compile in a background process):
# deterministic on a clean clone. tests/test_kernel_choice.py tests "auto" itself.
os.environ.setdefault("LTV_LSTM_MPC_KERNEL", "numba")

# Property tests: deterministic in CI, a little more thorough locally on request.
settings.register_profile(
    "default",
    max_examples=40,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.register_profile("thorough", max_examples=400, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))
