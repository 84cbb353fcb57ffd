r"""(epsilon, beta) statements from campaigns: exact binomial bounds on failure probabilities.

A campaign's closed loops are Bernoulli trials for a boolean outcome (a constraint
violated, a final offset above a tolerance, an infeasible step). When the loops of a
stratum are independent and identically distributed draws of the campaign's random
factors (``[random]`` of the spec: sampled mismatch parameters, noise levels and noise
seeds; the fixed settings and ``[factors]`` levels define the strata, each stated on its
own), the number of failures :math:`k` among :math:`N` loops is binomial with the
unknown probability :math:`p` of a failure in a loop of that family, and the one-sided
Clopper-Pearson bound

.. math::

    \bar\varepsilon(k, N, \beta) = \max\{p : P(\mathrm{Bin}(N, p) \le k) \ge \beta\}
    = F^{-1}_{\mathrm{Beta}(k + 1,\, N - k)}(1 - \beta) \quad (k < N), \qquad
    \bar\varepsilon = 1 \quad (k = N)

gives the statement: *with confidence* :math:`1 - \beta`, :math:`p \le \bar\varepsilon`
(Clopper & Pearson, Biometrika 26, 1934). With no failures it is
:math:`1 - \beta^{1/N}`, so :math:`N \ge \ln\beta / \ln(1 - \varepsilon)` loops without a
failure state :math:`p \le \varepsilon` (:func:`loops_needed`). The statement is about
the family the draws come from (the distributions of the spec), not about other plants.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.validation import expect_int, expect_real

__all__ = [
    "Outcome",
    "Statement",
    "campaign_statements",
    "clopper_pearson_upper",
    "default_outcomes",
    "format_statements",
    "loops_needed",
]


def _probability(name: str, value: float) -> float:
    expect_real(name, value, low=0.0, high=1.0, low_open=True, high_open=True)
    return float(value)


def clopper_pearson_upper(failures: int, loops: int, beta: float) -> float:
    r"""One-sided Clopper-Pearson upper bound :math:`\bar\varepsilon(k, N, \beta)` (see
    the module docstring).

    Parameters
    ----------
    failures : int
        :math:`k`, failures observed (0 <= k <= N).
    loops : int
        :math:`N` >= 1 i.i.d. loops.
    beta : float
        :math:`\beta` in (0, 1): 1 - confidence.

    Returns
    -------
    float
        The bound: with confidence :math:`1 - \beta` the failure probability is at most
        this (1 when every loop failed).
    """
    from scipy.stats import beta as beta_distribution

    expect_int("loops", loops, minimum=1)
    expect_int("failures", failures, minimum=0)
    beta = _probability("beta", beta)
    if failures > loops:
        raise InvalidValueError(f"failures ({failures}) cannot exceed loops ({loops})")
    if failures == loops:
        return 1.0
    if failures == 0:  # closed form, exact to rounding
        return float(-math.expm1(math.log(beta) / loops))
    return float(beta_distribution.ppf(1.0 - beta, failures + 1, loops - failures))


def loops_needed(epsilon: float, beta: float) -> int:
    r"""Smallest number :math:`N` of i.i.d. loops that, all without a failure, state
    :math:`p \le \varepsilon` with confidence :math:`1 - \beta`.

    Parameters
    ----------
    epsilon : float
        :math:`\varepsilon` in (0, 1), the failure probability to state.
    beta : float
        :math:`\beta` in (0, 1): 1 - confidence.

    Returns
    -------
    int
        :math:`N = \lceil \ln\beta / \ln(1 - \varepsilon) \rceil` (checked against
        :func:`clopper_pearson_upper` for rounding).
    """
    epsilon = _probability("epsilon", epsilon)
    beta = _probability("beta", beta)
    n = math.ceil(math.log(beta) / math.log1p(-epsilon))
    while n > 1 and clopper_pearson_upper(0, n - 1, beta) <= epsilon:  # rounding of ceil
        n -= 1
    while clopper_pearson_upper(0, n, beta) > epsilon:
        n += 1
    return n


@dataclass(frozen=True)
class Outcome:
    """A boolean outcome of one closed loop (a campaign row).

    Attributes
    ----------
    name : str
        Short name (a column of ``statements.csv``).
    description : str
        What a failure is, in words.
    failed : callable
        ``failed(row)`` -> True (failure), False, or None (not measurable in this row,
        e.g. a model without an output constraint): the row is then left out.
    """

    name: str
    description: str
    failed: Callable[[Mapping[str, Any]], bool | None]


#: Row column of the measured offset the ``offset`` outcome uses (:mod:`.task`).
OFFSET_COLUMN = "final_offset_mean"


def _greater(column: str, threshold: float) -> Callable[[Mapping[str, Any]], bool | None]:
    def failed(row: Mapping[str, Any]) -> bool | None:
        value = row.get(column)
        if value is None or (isinstance(value, float) and math.isnan(value)):
            return None
        return float(value) > threshold

    return failed


def _offset_failed(tolerance: float) -> Callable[[Mapping[str, Any]], bool | None]:
    mean, last = _greater(OFFSET_COLUMN, tolerance), _greater("final_offset", tolerance)

    def failed(row: Mapping[str, Any]) -> bool | None:
        return mean(row) if OFFSET_COLUMN in row else last(row)

    return failed


def default_outcomes(
    offset_tolerance: float = 1e-3, offset_window: int | None = None
) -> list[Outcome]:
    r"""The outcomes stated by default; ``offset_tolerance`` in output units.

    The ``offset`` outcome reads :data:`OFFSET_COLUMN`: the largest over the constant
    segments of :math:`|\mathrm{mean}(y_k - y^0_k)|` over the last samples of the segment
    (``offset_window`` of the spec, 1 = the last sample), on the noise-free plant output
    (the measurement noise is not in it; the loop's reaction to it is, and the mean
    filters it). A row without that column (older results) falls back to
    ``final_offset`` (the last sample).
    """
    window = "the last samples" if offset_window is None else f"the last {offset_window} samples"
    return [
        Outcome("violation", "the plant output violated its constraint", _greater("violations", 0)),
        Outcome(
            "violation_guarantee_held",
            "a violation on a step where Theorem 3's guarantee held",
            _greater("violations_guarantee_held", 0),
        ),
        Outcome(
            "offset",
            f"a final offset above {offset_tolerance:g} (output units; |mean error| of the "
            f"noise-free plant output over {window} of each constant segment)",
            _offset_failed(offset_tolerance),
        ),
        Outcome("infeasible", "an infeasible FHOCP step", _greater("infeasible_steps", 0)),
    ]


@dataclass(frozen=True)
class Statement:
    """The bound for one outcome in one stratum.

    Attributes
    ----------
    stratum : dict
        The fixed settings of the stratum (varying settings of the spec -> level).
    outcome : str
        :attr:`Outcome.name`.
    description : str
    failures, loops : int
        Failures among the loops that measured the outcome.
    beta : float
    upper_bound : float
        :func:`clopper_pearson_upper`; 1 when no loop of the stratum finished (nothing
        is known).
    errors : int
        Tasks of the stratum left out because they raised (not draws of the family's
        closed loops; count them as failures to be pessimistic).
    pooled : tuple of str
        The replication settings pooled into this stratum (e.g. ``("seed",)``).
    duplicates : int
        Rows counted once because they repeat another row's loop exactly: a noise seed
        without measurement noise (``noise_std = 0``) changes nothing, so such
        replications are one loop, not independent ones.
    """

    stratum: dict[str, Any]
    outcome: str
    description: str
    failures: int
    loops: int
    beta: float
    upper_bound: float
    errors: int = 0
    pooled: tuple[str, ...] = ()
    duplicates: int = 0

    def sentence(self) -> str:
        """The statement in words."""
        left_out = f"; {self.errors} task(s) with errors left out" if self.errors else ""
        if self.pooled:
            left_out += f"; {', '.join(self.pooled)} pooled"
        if self.duplicates:
            left_out += (
                f"; {self.duplicates} noise-free replication(s) of the same loop counted once"
            )
        return (
            f"with confidence {1 - self.beta:.0%}, P({self.description}) <= "
            f"{self.upper_bound:.3g} ({self.failures} of {self.loops} loops{left_out})"
        )


def campaign_statements(
    rows: Sequence[Mapping[str, Any]],
    strata: Sequence[str],
    *,
    beta: float = 0.05,
    offset_tolerance: float = 1e-3,
    outcomes: Sequence[Outcome] | None = None,
    replications: Sequence[str] = (),
    offset_window: int | None = None,
) -> list[Statement]:
    """Bounds for every outcome in every stratum of a campaign's rows.

    Parameters
    ----------
    rows : sequence of dict
        Campaign rows; rows whose status is not ``"ok"`` are left out and counted in
        :attr:`Statement.errors` (a stratum with no finished row gets the bound 1).
    strata : sequence of str
        The settings whose levels define the strata (the spec's ``[factors]`` and
        ``[[cases]]`` keys; not the random ones).
    beta : float
        1 - confidence.
    offset_tolerance : float
        Of the ``offset`` outcome, output units.
    outcomes : sequence of Outcome, optional
        Default :func:`default_outcomes`.
    replications : sequence of str
        Replication settings (``CampaignSpec.replications``)
        pooled into each stratum (they must not be in ``strata``). Rows of a stratum that
        differ only in the noise ``seed`` and have ``noise_std = 0`` are one loop and count
        once (:attr:`Statement.duplicates`).
    offset_window : int, optional
        The window of the measured offset, for the outcome's description.
    """
    beta = _probability("beta", beta)
    expect_real("offset_tolerance", offset_tolerance, low=0.0)
    overlap = sorted(set(strata) & set(replications))
    if overlap:
        raise InvalidValueError(f"{overlap} are both strata and replications: choose one")
    chosen = (
        list(outcomes)
        if outcomes is not None
        else default_outcomes(offset_tolerance, offset_window)
    )
    groups: dict[tuple[Any, ...], list[Mapping[str, Any]]] = {}
    for row in rows:
        groups.setdefault(tuple(row.get(name) for name in strata), []).append(row)
    pooled = tuple(name for name in replications if len({repr(row.get(name)) for row in rows}) > 1)
    statements = []
    for levels, members in groups.items():
        stratum = dict(zip(strata, levels, strict=True))
        finished, duplicates = _distinct_loops(
            [row for row in members if row.get("status") == "ok"]
        )
        errors = len(members) - len(finished) - duplicates
        for outcome in chosen:
            measured = [v for v in (outcome.failed(row) for row in finished) if v is not None]
            if finished and not measured:  # not measurable here (e.g. no output constraint)
                continue
            failures = sum(measured)
            bound = clopper_pearson_upper(failures, len(measured), beta) if measured else 1.0
            statements.append(
                Statement(
                    stratum,
                    outcome.name,
                    outcome.description,
                    failures,
                    len(measured),
                    beta,
                    bound,
                    errors,
                    pooled,
                    duplicates,
                )
            )
    return statements


def _distinct_loops(rows: Sequence[Mapping[str, Any]]) -> tuple[list[Mapping[str, Any]], int]:
    """The rows without exact repeats of a loop, and how many were dropped: rows with
    ``noise_std = 0`` whose settings agree except the noise ``seed`` ran the same
    deterministic loop."""
    from ltv_lstm_mpc.campaign.spec import SETTINGS

    seen: set[str] = set()
    distinct: list[Mapping[str, Any]] = []
    for row in rows:
        noise = row.get("noise_std")
        if noise is None or float(noise) != 0.0:
            distinct.append(row)
            continue
        identity = repr(sorted((k, repr(row[k])) for k in row if k in SETTINGS and k != "seed"))
        if identity not in seen:
            seen.add(identity)
            distinct.append(row)
    return distinct, len(rows) - len(distinct)


def format_statements(statements: Sequence[Statement]) -> list[str]:
    """Markdown table lines of the statements (for ``report.md``)."""
    if not statements:
        return []
    strata = list(statements[0].stratum)
    head = " | ".join(strata) if strata else "stratum"
    lines = [
        f"| {head} | outcome | failures / loops | errors left out | upper bound (confidence "
        f"{1 - statements[0].beta:.0%}) |",
        "|---|" + "---|" * max(len(strata) - 1, 0) + "---|---|---|---|",
    ]
    for statement in statements:
        cells = " | ".join(str(v) for v in statement.stratum.values()) if strata else "all"
        lines.append(
            f"| {cells} | {statement.description} | {statement.failures} / {statement.loops} "
            f"| {statement.errors} | {statement.upper_bound:.3g} |"
        )
    pooled = sorted({name for statement in statements for name in statement.pooled})
    if pooled:
        lines += [
            "",
            f"Replications pooled into each stratum: {', '.join(pooled)} (its levels repeat "
            "the stratum's loop with other noise; they are loops of one statement, not strata).",
        ]
    duplicates = max((statement.duplicates for statement in statements), default=0)
    if duplicates:
        lines += [
            "",
            "Rows without measurement noise (noise_std = 0) that differ only in the noise "
            "seed are one deterministic loop and count once (the loops column counts "
            "distinct loops).",
        ]
    return lines
