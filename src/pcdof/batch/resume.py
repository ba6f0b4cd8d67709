"""``--resume``: which frames an earlier run in the output folder finished from the same inputs and settings."""

from __future__ import annotations

import json

from ..errors import InputError


def _read_report(report_path: str) -> dict:
    """The report at *report_path* as a dict; {} when it is missing, unreadable or not an object."""
    try:
        with open(report_path, encoding="utf-8") as f:
            previous = json.load(f)
    except (OSError, ValueError, RecursionError):
        return {}
    return previous if isinstance(previous, dict) else {}


def _check_settings(old_settings, settings: dict) -> None:
    if not isinstance(old_settings, dict):
        return
    current = json.loads(json.dumps(settings))  # same JSON normalisation as the stored copy
    differ = sorted(k for k in set(old_settings) | set(current) if old_settings.get(k) != current.get(k))
    if differ:
        raise InputError(
            f"--resume: the output folder was rendered with different settings ({', '.join(differ)}); "
            f"use a new output folder, or run without --resume to render every frame again"
        )


def check_resume(report_path: str, settings: dict, inputs: list[tuple[str, str]]) -> dict[int, dict]:
    """Frames the previous run in the folder finished from the same inputs (their outputs may be kept).

    InputError when it used other settings, or rendered any frame index from other colour / depth
    files (another sequence, or a different list file): mixing the two runs' frames is refused.

    Parameters
    ----------
    report_path : str, the previous run's report.json (missing or unreadable: nothing is kept)
    settings : dict, this run's settings
    inputs : list of (colour, depth) paths relative to the input root, one per frame of this run

    Returns
    -------
    {frame index: its record} for the frames recorded "ok" or "skipped" from the same input paths (the
    caller compares their input stamps and lens with this run's)
    """
    previous = _read_report(report_path)
    if not previous:
        return {}
    _check_settings(previous.get("settings"), settings)
    done = {}
    frames = previous.get("frames")
    for rec in frames if isinstance(frames, list) else []:
        if not isinstance(rec, dict):
            continue
        i = rec.get("index")
        if not isinstance(i, int) or not 0 <= i < len(inputs):
            continue
        recorded = (rec.get("color"), rec.get("depth"))
        if recorded != inputs[i]:
            raise InputError(
                f"--resume: frame {i} in the output folder was rendered from {recorded[0]} + {recorded[1]}, "
                f"not {inputs[i][0]} + {inputs[i][1]} (another sequence or list file); use a new output folder, "
                f"or run without --resume to render every frame again"
            )
        if rec.get("status") in ("ok", "skipped"):
            done[i] = rec
    return done


def unchanged(previous: dict, rec: dict) -> bool:
    """Whether a frame's earlier record *previous* was made from the inputs and lens of this run's *rec*."""
    return (isinstance(previous.get("source"), dict) and previous["source"] == rec["source"]
            and all(previous.get(k) == rec[k] for k in ("focus_distance_m", "f_number", "focal_length_mm")))
