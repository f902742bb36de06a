"""Per-run rows of an evaluation grid, written the moment each run finishes.

A grid of closed-loop runs takes hours; cut off (a time limit, Ctrl-C, a lost
machine) it must lose at most the runs in flight. :class:`RowLog` appends one
CSV row (and, if asked, one JSON line) per finished run and flushes it to disk
at once; :func:`read_rows` reads such a CSV back, typed, so that a re-run with
``--resume`` skips what is there and summarises everything.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import threading
from pathlib import Path

from amhe_cli.errors import AmheError

#: Columns of an evaluation CSV, in order; ``setting`` is the swept setting of the run (``mhe.samples=6``),
#: empty outside a sweep.
ROW_KEYS = ("task", "mode", "seed", "success", "e_g", "J", "t_exec", "rmse", "fell", "recoveries", "control_hz",
            "setting")
#: Headers of earlier amhe versions that :func:`read_rows` still reads: before the fall reflex's
#: ``recoveries`` (read as 0), and before sweeps (no ``setting``).
_LEGACY_KEYS = (tuple(k for k in ROW_KEYS if k != "recoveries"),
                tuple(k for k in ROW_KEYS if k not in ("recoveries", "setting")))
_TYPES = {"task": str, "mode": str, "seed": int, "success": lambda v: v == "True", "fell": lambda v: v == "True",
          "recoveries": int, "setting": str}


def read_rows(path: str | os.PathLike) -> list[dict]:
    """The rows of an evaluation CSV written by :class:`RowLog`, typed (ints, floats, bools).

    A last line cut off mid-write (the process was killed) is dropped.

    Raises:
        AmheError: the file's header is not :data:`ROW_KEYS`, or a complete row does not parse.
    """
    path = Path(path)
    with path.open(newline="") as fh:
        lines = fh.read().splitlines(keepends=True)
    if not lines:
        return []
    if lines and not lines[-1].endswith("\n"):
        lines = lines[:-1]  # a row cut off mid-write
    reader = csv.reader(lines)
    header = next(reader, None)
    if header is None:
        return []
    keys = tuple(header)
    if keys != ROW_KEYS and keys not in _LEGACY_KEYS:
        raise AmheError(f"{path}: not an amhe evaluate CSV (columns {', '.join(header)}; expected "
                        f"{', '.join(ROW_KEYS)})")
    rows = []
    for i, values in enumerate(reader, start=2):
        if len(values) != len(keys):
            raise AmheError(f"{path}, line {i}: {len(values)} values, expected {len(keys)}")
        try:
            rows.append({"setting": "", "recoveries": 0, **{k: _TYPES.get(k, float)(v) for k, v in zip(keys, values)}})
        except ValueError:
            raise AmheError(f"{path}, line {i}: a value does not parse: {values}") from None
    return rows


class RowLog:
    """Append-only CSV (and JSON-lines) of grid rows, each flushed to disk as it is written.

    Args:
        csv_path: the CSV; its header is written when the file is new or empty.
        jsonl_path: optional JSON-lines file, one object per row (all keys of the row).
    """

    def __init__(self, csv_path: str | os.PathLike, jsonl_path: str | os.PathLike | None = None):
        self.csv_path = Path(csv_path)
        new = not self.csv_path.exists() or self.csv_path.stat().st_size == 0
        if not new:
            with self.csv_path.open(newline="") as fh:
                header = tuple(next(csv.reader(fh), ()))
            if header != ROW_KEYS:
                raise AmheError(f"{self.csv_path}: its columns are not this amhe's ({', '.join(ROW_KEYS)}): "
                                "start the grid anew with --force, or give another --out")
        self._csv = self.csv_path.open("a", newline="")
        self._writer = csv.writer(self._csv)
        if new:
            self._writer.writerow(ROW_KEYS)
            self._flush(self._csv)
        self._jsonl = Path(jsonl_path).open("a") if jsonl_path is not None else None

    @staticmethod
    def _flush(fh) -> None:
        fh.flush()
        os.fsync(fh.fileno())

    def write(self, row: dict) -> None:
        """Append one run's row (keys :data:`ROW_KEYS`, more allowed in the JSON line) and flush it.

        A Ctrl-C (SIGINT) arriving while the row goes to the files is held and
        acted on right after, so a cut-off grid never has a row in the CSV (what
        ``--resume`` reads) that its JSON lines lack.
        """
        held: list = []
        previous = None
        if threading.current_thread() is threading.main_thread():  # Python runs handlers there only
            previous = signal.signal(signal.SIGINT, lambda *args: held.append(args))
        try:
            self._writer.writerow([row.get(k, "") for k in ROW_KEYS])
            self._flush(self._csv)
            if self._jsonl is not None:
                self._jsonl.write(json.dumps(row, default=float) + "\n")
                self._flush(self._jsonl)
        finally:
            if previous is not None:
                signal.signal(signal.SIGINT, previous)
                if held:
                    if callable(previous):
                        previous(*held[0])
                    else:
                        raise KeyboardInterrupt

    def close(self) -> None:
        self._csv.close()
        if self._jsonl is not None:
            self._jsonl.close()

    def __enter__(self) -> "RowLog":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
