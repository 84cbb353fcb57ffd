"""One closed-loop benchmark abstraction, shared by ``ltv-lstm-mpc reproduce``'s benchmarks.

A :class:`Benchmark` is a true plant (a name of the plant registry), a default model, named
scenarios, how one scenario runs on one solver path, how its outputs are written (CSV, JSON,
plot), the certificate numbers reported next to them and the printed report.
:meth:`Benchmark.reproduce` is the one driver: it selects scenarios, runs them on every
solver path, writes the files and ``summary.json``, and raises the same errors for every
benchmark. Two ship: ``PAPER_BENCHMARK`` (the pH scenarios of Section V,
:mod:`ltv_lstm_mpc.paper.reproduce`) and ``QUADTANK_BENCHMARK`` (the quadruple tank,
:mod:`ltv_lstm_mpc.benchmarks.quadtank`); the command line finds them by name.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.lstm.model import LSTMModel

__all__ = ["Benchmark"]


@dataclass(frozen=True)
class Benchmark:
    """A reproducible closed-loop benchmark.

    Attributes
    ----------
    name : str
        ``reproduce --benchmark NAME``.
    plant : str
        The true plant, a name of :mod:`ltv_lstm_mpc.plants.registry`.
    model : str
        Default model (a shipped file name).
    scenarios : callable
        ``scenarios(model, short)`` -> the scenarios (each with a ``name``).
    run : callable
        ``run(scenario, model, solver, progress)`` -> a result with ``summary()``;
        ``solver`` None: the scenario's own.
    write : callable
        ``write(result, out, plot)`` -> the summary, after writing the result's files.
    certificate_key : str
        Key of the certificate numbers in the report.
    certificate : callable
        ``certificate(model, results)`` -> the certificate numbers reported.
    format_report : callable
        ``format_report(report)`` -> the printed table and certificate lines.
    solvers : tuple
        Default solver paths (``(None,)``: each scenario's own configuration).
    """

    name: str
    plant: str
    model: str
    scenarios: Callable[[LSTMModel, bool], Sequence[Any]]
    run: Callable[[Any, LSTMModel, str | None, bool, str], Any]
    write: Callable[[Any, Path, bool], dict[str, Any]]
    certificate_key: str
    certificate: Callable[[LSTMModel, list[Any]], dict[str, Any]]
    format_report: Callable[[dict[str, Any]], str]
    solvers: tuple[str | None, ...] = (None,)

    def select(self, model: LSTMModel, only: Sequence[str] | None, short: bool) -> list[Any]:
        """The scenarios whose name contains one of ``only`` (all without it).

        Raises
        ------
        InvalidValueError
            None matches (the message lists the scenario names).
        """
        chosen = [
            sc for sc in self.scenarios(model, short) if not only or any(o in sc.name for o in only)
        ]
        if not chosen:
            names = [sc.name for sc in self.scenarios(model, True)]
            raise InvalidValueError(
                f"no {self.name} scenario matches {list(only or [])}; scenarios: {names}"
            )
        return chosen

    def reproduce(
        self,
        model: LSTMModel,
        out: Path | None = None,
        *,
        only: Sequence[str] | None = None,
        solvers: Sequence[str | None] | None = None,
        short: bool = False,
        progress: bool = True,
        plot: bool = True,
        model_info: dict[str, Any] | None = None,
        engine: str = "auto",
    ) -> dict[str, Any]:
        """Run the scenarios on every solver path; optionally write the outputs
        (``engine``: the controllers' step engine, ``OffsetFreeController(engine=...)``).

        Returns
        -------
        dict
            ``{"model": ..., "scenarios": [summary, ...], <certificate_key>: {...},
            "wall_time_s": float}``; also written to ``out/summary.json`` when ``out`` is
            given.
        """
        start = time.perf_counter()
        scenarios = self.select(model, only, short)
        paths = tuple(solvers) if solvers is not None else self.solvers
        summaries, results = [], []
        for scenario in scenarios:
            for solver in paths:
                result = self.run(scenario, model, solver, progress, engine)
                results.append(result)
                summaries.append(
                    self.write(result, out, plot) if out is not None else result.summary()
                )
        report = {
            "model": model_info or {},
            "scenarios": summaries,
            self.certificate_key: self.certificate(model, results),
            "wall_time_s": time.perf_counter() - start,
        }
        if out is not None:
            out.mkdir(parents=True, exist_ok=True)
            (out / "summary.json").write_text(json.dumps(report, indent=2))
        return report
