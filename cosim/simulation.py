"""Running an FMU with ``fmpy.simulate_fmu`` (host side): :func:`simulate`, which raises on a refused step.

fmpy.simulate_fmu ends quietly when a step is refused (fmi2Discard + fmi2Terminated) and returns the
result up to the last good communication point; :func:`simulate` raises :class:`StepRefusedError`
instead.  :func:`input_table` builds fmpy's input format.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from .unit import captured_slave_log, import_hygiene

__all__ = ["StepRefusedError", "input_table", "simulate"]


class StepRefusedError(RuntimeError):
    """An FMU refused a step (fmi2Discard) during ``simulate``; ``.messages`` has its log."""

    def __init__(self, message: str, messages: list[str], result: np.ndarray | None):
        super().__init__(message)
        self.messages = messages
        self.result = result


def input_table(time: Sequence[float], **signals: Sequence[float]) -> np.ndarray:
    """Structured array in fmpy's input format: a 'time' column and one column per input."""
    time = np.asarray(time, dtype=float)
    dtype = [("time", np.float64)]
    columns = [time]
    for name, values in signals.items():
        values = np.asarray(values)
        if values.shape != time.shape:
            raise ValueError(f"input {name!r}: {values.shape} values for {time.shape} times")
        dtype.append((name, np.bool_ if values.dtype == bool else
                      (np.int32 if np.issubdtype(values.dtype, np.integer) else np.float64)))
        columns.append(values)
    table = np.empty(time.shape, dtype=dtype)
    for (name, _), column in zip(dtype, columns):
        table[name] = column
    return table


def simulate(fmu_path: str | os.PathLike, *, stop_time: float, step_size: float, start_time: float = 0.0,
             inputs: np.ndarray | None = None, start_values: Mapping[str, Any] | None = None,
             outputs: Sequence[str] | None = None, raise_on_refusal: bool = True,
             log: list[str] | None = None) -> np.ndarray:
    """Smoke simulation with ``fmpy.simulate_fmu`` (communication step = ``step_size``).

    fmpy.simulate_fmu ends quietly when a step is refused (fmi2Discard + fmi2Terminated) and returns
    the result up to the last good communication point.  Here the FMU log is captured (debug logging
    on) and :class:`StepRefusedError` is raised if any message has status >= fmi2Discard or the
    result stops before ``stop_time``.  ``log`` (optional) receives every FMU log line.
    """
    import fmpy
    from fmpy.fmi2 import fmi2Discard

    captured: list[tuple[int, str]] = []

    def logger(_component, _instance, status, _category, message):
        captured.append((int(status), message.decode("utf-8", "replace") if message else ""))

    with import_hygiene(), captured_slave_log() as records:
        result = fmpy.simulate_fmu(str(fmu_path), start_time=start_time, stop_time=stop_time,
                                   step_size=step_size, output_interval=step_size, input=inputs,
                                   start_values=dict(start_values or {}), output=outputs,
                                   debug_logging=True, logger=logger, fmi_type="CoSimulation")
    if log is not None:
        log.extend(m for _, m in captured)
    refusals = [m for s, m in captured if s >= fmi2Discard] or [m for m in records if "refused" in m]
    end = float(result["time"][-1]) if len(result) else start_time
    truncated = end < stop_time - 1e-9 * max(1.0, abs(stop_time))
    if raise_on_refusal and (refusals or truncated):
        what = "; ".join(refusals) or f"result ends at t={end} < stop_time={stop_time}"
        raise StepRefusedError(f"{Path(fmu_path).name}: simulation stopped at t={end}: {what}",
                               refusals, result)
    return result
