"""Log lines with short numbers: floats rounded to 4 significant digits (JSON keeps them whole).

``install_float_rounding()`` wraps the process' log-record factory once, so every
``log.info("... %s", value)`` of every module prints ``0.1235`` rather than
``0.12345678901234``; dicts, lists and tuples of floats too, whatever handlers Hydra installs or
replaces later (it reconfigures logging around every job). Strings are left alone (overrides
and commands stay exact). metrics.json, run.json and the study keep full precision.
"""

from __future__ import annotations

import logging
import numbers
from typing import Any

SIGNIFICANT_DIGITS = 4


def round_floats(value: Any, digits: int = SIGNIFICANT_DIGITS, _depth: int = 0) -> Any:
    """``value`` with every float (also inside dicts, lists, tuples) cut to ``digits`` digits."""
    if isinstance(value, bool) or isinstance(value, numbers.Integral):
        return value
    if isinstance(value, numbers.Real):
        number = float(value)
        return float(f"{number:.{digits}g}") if number == number and abs(number) != float("inf") else number
    if _depth > 4:
        return value
    if isinstance(value, dict):
        return {k: round_floats(v, digits, _depth + 1) for k, v in value.items()}
    if isinstance(value, (list, tuple)) and len(value) <= 64:
        rounded = [round_floats(v, digits, _depth + 1) for v in value]
        return rounded if isinstance(value, list) else tuple(rounded)
    return value


_installed = False


def install_float_rounding() -> None:
    """Round the float arguments of every log record created from now on (idempotent)."""
    global _installed
    if _installed:
        return
    make_record = logging.getLogRecordFactory()

    def rounded_record(*args: Any, **kwargs: Any) -> logging.LogRecord:
        record = make_record(*args, **kwargs)
        if record.args:
            if isinstance(record.args, dict):
                record.args = round_floats(record.args)
            else:
                record.args = tuple(round_floats(a) for a in record.args)
        return record

    logging.setLogRecordFactory(rounded_record)
    _installed = True


_quiet = False


def quiet_log_write_errors() -> None:
    """A log file that cannot be written (a full disk) says so in one line, once per file.

    Python's default prints a traceback for every record a handler fails to write: on a full
    disk, dozens of them bury the one line that says what happened (idempotent).
    """
    global _quiet
    if _quiet:
        return
    import sys

    warned: set[str] = set()

    def handle_error(self: logging.Handler, record: logging.LogRecord) -> None:
        error = sys.exc_info()[1]
        target = getattr(self, "baseFilename", None) or type(self).__name__
        if target in warned:
            return
        warned.add(target)
        try:
            print(f"aslexp: cannot write the log {target} ({error}); its records are lost until "
                  "this is fixed, the console keeps them", file=sys.stderr, flush=True)
        except OSError:
            pass

    logging.Handler.handleError = handle_error  # type: ignore[method-assign]
    _quiet = True
