"""A batch's report.json (written atomically, with snapshots while it runs), its progress bar and exit status."""

from __future__ import annotations

import contextlib
import datetime as _dt
import logging
import os
import sys
import time

from ..errors import PcdofError
from ..sources.discovery import Sequence
from .outputs import REPORT_NAME
from .signals import interrupted_by

log = logging.getLogger("pcdof.batch")

#: Exit status of a batch: every frame written.
EXIT_OK = 0
#: Exit status of a batch: some frames failed, the others were written (partial result).
EXIT_PARTIAL = 10
#: Exit status of a batch: no frame was written.
EXIT_ALL_FAILED = 11
#: Seconds between progress snapshots of report.json while a batch runs.
REPORT_INTERVAL_S = 5.0


def exit_code(report: dict) -> int:
    """:data:`EXIT_OK`, :data:`EXIT_PARTIAL` or :data:`EXIT_ALL_FAILED` for a finished report."""
    t = report["totals"]
    video_failed = bool(report.get("video") and report["video"].get("error"))
    if t["failed"] == 0 and not video_failed:
        return EXIT_OK
    if t["ok"] + t["skipped"] == 0:
        return EXIT_ALL_FAILED
    return EXIT_PARTIAL


def progress_bar(iterable=None, progress=True, **kw):
    from tqdm.auto import tqdm

    return tqdm(iterable, disable=not progress, file=sys.stderr, dynamic_ncols=True, **kw)


def now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _totals(recs: list[dict], wall: float) -> dict:
    rendered = [r for r in recs if r["status"] in ("ok", "failed") and r["worker"] is not None]  # ran somewhere
    return {
        "frames": len(recs),
        "ok": sum(r["status"] == "ok" for r in recs),
        "failed": sum(r["status"] == "failed" for r in recs),
        "skipped": sum(r["status"] == "skipped" for r in recs),
        "pending": sum(r["status"] == "pending" for r in recs),
        "wall_seconds": round(wall, 6),
        "frame_seconds_sum": round(sum(r["seconds"] for r in rendered), 6),
        "frames_per_second": round(len(rendered) / wall, 4) if wall > 0 and rendered else None,
    }


class Reporter:
    """Collects frame records, writes report.json atomically (snapshots while running)."""

    def __init__(self, path: str, header: dict, records: list[dict], progress: bool):
        self.path, self.header, self.records = path, header, records
        self.t0 = time.perf_counter()
        self.last_write = 0.0
        todo = sum(r["status"] == "pending" for r in records)
        self.bar = progress_bar(None, progress, total=todo, desc="render", unit="frame")

    def add(self, rec: dict) -> None:
        self.records[rec["index"]] = rec
        if rec["status"] == "failed":
            log.warning("frame %d (%s) failed: %s", rec["index"], rec["color"], rec["error"])
        self.bar.update(1)
        failed = sum(r["status"] == "failed" for r in self.records)
        if failed:
            self.bar.set_postfix(failed=failed, refresh=False)
        if time.perf_counter() - self.last_write > REPORT_INTERVAL_S:
            self.write("running")

    def report(self, status: str) -> dict:
        totals = _totals(self.records, time.perf_counter() - self.t0)
        return {**self.header, "status": status, "finished": now(), "totals": totals, "frames": self.records}

    def write(self, status: str, extra: dict | None = None) -> dict:
        from .. import io

        rep = self.report(status)
        if extra:
            rep.update(extra)
        io.write_json(self.path, rep)
        self.last_write = time.perf_counter()
        return rep

    def stopped(self, err: BaseException) -> None:
        """Close the bar and write the report of a batch that *err* stopped: "interrupted" or "error"."""
        self.close()
        if isinstance(err, KeyboardInterrupt):
            self.write("interrupted", {"error": f"interrupted by {interrupted_by(err)}"})
        else:
            self.write("error", {"error": f"{type(err).__name__}: {err}"})

    def finish(self, extra: dict) -> dict:
        """The final report with *extra* (e.g. the video), its status and exit code, written to report.json."""
        from .. import io

        rep = self.report("done")
        rep.update(extra)
        code = exit_code(rep)
        rep["status"] = {EXIT_OK: "ok", EXIT_PARTIAL: "partial", EXIT_ALL_FAILED: "failed"}[code]
        rep["exit_code"] = code
        io.write_json(self.path, rep)
        return rep

    def close(self) -> None:
        self.bar.close()


def report_interrupted_early(output_dir: str, sequence: Sequence, n: int, err: BaseException) -> None:
    """report.json for a batch stopped before its first frame (in the focus pass): status "interrupted".

    An earlier run's report in the folder keeps its frames and settings (nothing of them was touched),
    so that ``--resume`` still keeps what that run rendered.
    """
    import json

    from .. import io

    note = {"status": "interrupted", "finished": now(),
            "error": f"interrupted by {interrupted_by(err)} in the focus pass, before any frame was rendered"}
    path = os.path.join(output_dir, REPORT_NAME)
    try:
        with open(path, encoding="utf-8") as f:
            report = json.load(f)
    except (OSError, ValueError, RecursionError):
        report = None
    if not isinstance(report, dict):
        report = {"report": "pcdof batch", "started": note["finished"],
                  "input": {"path": sequence.root, "layout": sequence.layout, "pairs": len(sequence)},
                  "output_dir": output_dir, "totals": {"frames": n, "ok": 0, "failed": 0, "skipped": 0, "pending": n},
                  "frames": []}
    with contextlib.suppress(PcdofError):
        io.write_json(path, {**report, **note})
