"""The session's recording: JSON lines, one record per frame (hex), order, wish
and pose, each with its session time.  `rovlink replay` plays it back."""

from __future__ import annotations

import json
import threading
from pathlib import Path


class Recorder:
    """Writes records as they come, one line each (line-buffered: a crash loses
    at most the line being written); without a path it writes nothing."""

    def __init__(self, path: str | Path | None, meta: dict) -> None:
        self.path = Path(path) if path else None
        self._file = None
        self._lock = threading.Lock()
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file = open(self.path, "w", buffering=1, encoding="utf-8")
            self.write({"k": "meta", "t": 0.0, **meta})

    def write(self, record: dict) -> None:
        if self._file is None:
            return
        line = json.dumps(record, separators=(",", ":"))
        with self._lock:
            if self._file is not None:
                self._file.write(line + "\n")

    def close(self) -> None:
        with self._lock:
            if self._file is not None:
                self._file.close()
                self._file = None
