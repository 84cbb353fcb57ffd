"""numba's ``njit`` where numba is installed, else a stand-in that leaves a function as Python.

The one home of the guard used by every compiled kernel (the LSTM kernel, the dense solver
layer's loops, the DAQP binding): numba is a core dependency, but without it the package
still imports and runs its numpy reference code (``AVAILABLE`` is then ``False``).
"""

from __future__ import annotations

from typing import Any

__all__ = ["AVAILABLE", "REDUCTIONS", "njit"]

try:  # pragma: no cover - numba is a core dependency
    from numba import njit

    AVAILABLE = True
except ImportError:  # pragma: no cover - exercised in a subprocess by the tests
    AVAILABLE = False

    def njit(*args: Any, **kwargs: Any) -> Any:  # type: ignore[no-redef]
        """Stand-in: returns the Python function unchanged."""

        def wrap(function: Any) -> Any:
            return function

        return wrap


#: LLVM flags of the compiled loops whose sums may run in any order (vectorized reductions,
#: fused multiply-adds): results within a few ulps of the sequential sums. No "fast" flags
#: that assume finite values: NaN and inf still propagate and are caught by the callers'
#: checks. One definition for every kernel that uses them.
REDUCTIONS = {"reassoc", "contract"}
