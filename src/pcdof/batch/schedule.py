"""Lens settings over time: a fixed lens, keyframed focus / f-number, or focus that follows a pixel.

Every function here is pure and decides the whole sequence's lens before any frame is rendered,
so frames can be rendered in any order, on any number of workers, with identical results.

Focus that follows a pixel (``--focus-at X,Y``) measures the depth there in every frame and
smooths that track in two causal steps, both on inverse depth (dioptres), because the circle of
confusion c(z) = A*fx*|1/d_f - 1/z| is linear in 1/d_f: a focus error of one dioptre looks the
same near and far, and depth-sensor noise (which grows like z^2) becomes roughly uniform.

1. A running median over the last ``median_window`` frames removes spikes and dropouts
   (a hand crossing the focus point for a frame or two, a missing measurement).
2. A one-euro filter (Casiez, Roussel and Vogel, CHI 2012) removes the remaining jitter: an
   exponential smoother whose cut-off frequency rises with the speed of the signal, so a still
   subject gets heavy smoothing (no focus breathing) and a moving one is followed with little lag.

Both steps are causal -- the focus of frame i depends only on frames 0..i, like a camera's
autofocus -- so a run limited to the first N frames renders them exactly as the full run does,
and ``--resume`` after ``--limit`` gives the same images.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..errors import InputError, LensError
from ..lens import MAX_FOCUS_DISTANCE_M, MIN_FOCUS_DISTANCE_M, PaperLens, ThinLens, focus_distance, positive_number


def _linear(t: np.ndarray) -> np.ndarray:
    return t


def _smoothstep(t: np.ndarray) -> np.ndarray:
    # C1-continuous ease in / ease out: 3t^2 - 2t^3 (zero slope at every keyframe)
    return t * t * (3.0 - 2.0 * t)


#: Keyframe easing functions: map the fraction t in [0, 1] between two keyframes to a blend weight.
EASINGS = {"linear": _linear, "smoothstep": _smoothstep}


def parse_keyframes(text: str, *, name: str = "keyframes") -> tuple[tuple[int, float], ...]:
    """Parse ``"FRAME:VALUE,FRAME:VALUE,..."`` (e.g. ``"0:1.2,50:3.0"``) into sorted pairs.

    Parameters
    ----------
    text : str, comma-separated ``frame:value`` pairs; frame is a 0-based frame index, value > 0
    name : str, what the keyframes set (used in error messages)

    Returns
    -------
    tuple of (int, float), sorted by frame
    """
    if not isinstance(text, str) or not text.strip():
        raise InputError(f"{name} must be 'FRAME:VALUE[,FRAME:VALUE...]' (e.g. '0:1.2,50:3.0'); got {text!r}")
    out: dict[int, float] = {}
    for item in text.split(","):
        parts = item.strip().split(":")
        if len(parts) != 2:
            raise InputError(f"{name}: each keyframe must be FRAME:VALUE (e.g. 50:3.0); got {item.strip()!r}")
        try:
            frame_f = float(parts[0])
            value = float(parts[1])
        except ValueError:
            raise InputError(f"{name}: FRAME and VALUE must be numbers; got {item.strip()!r}") from None
        if not frame_f.is_integer() or frame_f < 0:
            raise InputError(f"{name}: FRAME must be an integer >= 0; got {parts[0]!r}")
        if not math.isfinite(value) or value <= 0:
            raise InputError(f"{name}: VALUE must be a finite number > 0; got {parts[1]!r}")
        frame = int(frame_f)
        if frame in out:
            raise InputError(f"{name}: frame {frame} appears more than once")
        out[frame] = value
    return tuple(sorted(out.items()))


def interpolate_keyframes(keyframes, n_frames: int, *, easing: str = "linear") -> np.ndarray:
    """Value of every frame from keyframes, eased between them and held before the first / after the last.

    Parameters
    ----------
    keyframes : sequence of (frame, value), as from :func:`parse_keyframes`
    n_frames : int, number of frames (>= 0)
    easing : a key of :data:`EASINGS`

    Returns
    -------
    (n_frames,) float64 ndarray

    Examples
    --------
    >>> interpolate_keyframes([(0, 1.0), (4, 3.0)], 6).tolist()
    [1.0, 1.5, 2.0, 2.5, 3.0, 3.0]
    """
    if easing not in EASINGS:
        raise InputError(f"easing must be one of {sorted(EASINGS)}; got {easing!r}")
    if isinstance(n_frames, bool) or not isinstance(n_frames, (int, np.integer)) or n_frames < 0:
        raise InputError(f"n_frames must be an integer >= 0; got {n_frames!r}")
    keys = sorted((int(f), float(v)) for f, v in keyframes)
    if not keys:
        raise InputError("keyframes must hold at least one FRAME:VALUE pair; got none")
    frames = np.array([k[0] for k in keys], dtype=np.float64)
    values = np.array([k[1] for k in keys], dtype=np.float64)
    if np.any(np.diff(frames) == 0):
        raise InputError(f"keyframes must have distinct frames; got {[k[0] for k in keys]}")
    i = np.arange(n_frames, dtype=np.float64)
    if len(keys) == 1:
        return np.full(n_frames, values[0])
    seg = np.clip(np.searchsorted(frames, i, side="right") - 1, 0, len(keys) - 2)
    t = np.clip((i - frames[seg]) / (frames[seg + 1] - frames[seg]), 0.0, 1.0)
    w = EASINGS[easing](t)
    return (1.0 - w) * values[seg] + w * values[seg + 1]  # exactly each keyframe's value at its frame


def running_median(values, window: int) -> np.ndarray:
    """Causal running median: out[i] = median of the known values among values[i - window + 1 .. i].

    Parameters
    ----------
    values : (n,) float ndarray, NaN = unknown
    window : int >= 1

    Returns
    -------
    (n,) float64 ndarray, NaN where the window holds no known value
    """
    x = np.asarray(values, dtype=np.float64)
    if x.ndim != 1:
        raise InputError(f"values must be 1-D; got shape {x.shape}")
    if isinstance(window, bool) or not isinstance(window, (int, np.integer)) or window < 1:
        raise InputError(f"median window must be an integer >= 1; got {window!r}")
    n = x.size
    if n == 0:
        return x.copy()
    window = min(int(window), n)  # a longer window sees the same values: never allocate more than the sequence
    padded = np.concatenate([np.full(window - 1, np.nan), x])
    windows = np.lib.stride_tricks.sliding_window_view(padded, window)
    out = np.full(n, np.nan)
    known = np.any(np.isfinite(windows), axis=1)
    if known.any():
        out[known] = np.nanmedian(windows[known], axis=1)
    return out


#: Frequencies accepted by the focus smoothing (frame rate and cut-offs), Hz: beyond MAX_RATE_HZ a cut-off
#: no longer smooths at any frame rate (alpha = 1 to double precision), and the filter's products stay finite.
MIN_RATE_HZ, MAX_RATE_HZ = 1e-3, 1e6
#: Largest one-euro speed coefficient (the cut-off rises by beta Hz per dioptre per second).
MAX_BETA = 1e6


def check_rate(name: str, value) -> float:
    """*value* as a float if it is a frequency in [MIN_RATE_HZ, MAX_RATE_HZ]; else an InputError naming *name*."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or not (
            math.isfinite(value) and MIN_RATE_HZ <= value <= MAX_RATE_HZ):
        raise InputError(f"{name} must be a finite number of Hz in [{MIN_RATE_HZ:g}, {MAX_RATE_HZ:g}]; got {value!r}")
    return float(value)


def one_euro(values, *, rate_hz: float, min_cutoff_hz: float = 0.5, beta: float = 1.0,
             d_cutoff_hz: float = 1.0) -> np.ndarray:
    """One-euro filter of a uniformly sampled signal (causal, deterministic).

    Parameters
    ----------
    values : (n,) float ndarray, all finite
    rate_hz : float, samples per second
    min_cutoff_hz : float, cut-off frequency when the signal is still (lower = smoother)
    beta : float >= 0, how fast the cut-off rises with the signal's speed (units of 1 / signal unit)
    d_cutoff_hz : float, cut-off of the speed estimate

    Returns
    -------
    (n,) float64 ndarray

    References
    ----------
    G. Casiez, N. Roussel, D. Vogel, "1 Euro Filter: A Simple Speed-based Low-pass Filter for
    Noisy Input in Interactive Systems", CHI 2012. alpha = 1 / (1 + tau / dt), tau = 1 / (2 pi fc).
    """
    x = np.asarray(values, dtype=np.float64)
    if x.ndim != 1 or not np.all(np.isfinite(x)):
        raise InputError("one_euro values must be a 1-D array of finite numbers")
    for label, v in (("rate_hz", rate_hz), ("min_cutoff_hz", min_cutoff_hz), ("d_cutoff_hz", d_cutoff_hz)):
        check_rate(label, v)
    if isinstance(beta, bool) or not (isinstance(beta, (int, float, np.integer, np.floating)) and math.isfinite(beta)
                                      and 0 <= beta <= MAX_BETA):
        raise InputError(f"beta must be a finite number in [0, {MAX_BETA:g}]; got {beta!r}")
    rate_hz, min_cutoff_hz, d_cutoff_hz, beta = float(rate_hz), float(min_cutoff_hz), float(d_cutoff_hz), float(beta)
    out = np.empty_like(x)
    if x.size == 0:
        return out
    dt = 1.0 / rate_hz

    def alpha(cutoff: float) -> float:
        return 1.0 / (1.0 + 1.0 / (2.0 * math.pi * cutoff * dt))

    a_d = alpha(d_cutoff_hz)
    prev, d_prev = x[0], 0.0
    out[0] = prev
    for i in range(1, x.size):
        d = (x[i] - prev) / dt
        d_prev = a_d * d + (1.0 - a_d) * d_prev
        a = alpha(min_cutoff_hz + beta * abs(d_prev))
        prev = a * x[i] + (1.0 - a) * prev
        out[i] = prev
    return out


def smooth_focus_track(raw_focus_m, *, rate_hz: float = 30.0, median_window: int = 5,
                       min_cutoff_hz: float = 0.5, beta: float = 1.0, d_cutoff_hz: float = 1.0) -> np.ndarray:
    """Flicker-free focus distances from per-frame measurements (running median, then one-euro).

    Both steps run on inverse depth (dioptres) and are causal. Unknown measurements (NaN, <= 0)
    are bridged: the median skips them, and a frame whose whole window is unknown keeps the
    previous frame's value (frames before the first measurement take the first measurement).

    Parameters
    ----------
    raw_focus_m : (n,) float ndarray, metres, NaN or <= 0 = no measurement
    rate_hz : float, frames per second of the sequence
    median_window : int, frames in the running median (1 = none)
    min_cutoff_hz, beta, d_cutoff_hz : one-euro parameters (see :func:`one_euro`); beta in 1/(dioptre/s)

    Returns
    -------
    (n,) float64 ndarray, metres, all finite and > 0
    """
    z = np.asarray(raw_focus_m, dtype=np.float64)
    if z.ndim != 1:
        raise InputError(f"raw_focus_m must be 1-D; got shape {z.shape}")
    if z.size == 0:
        return z.copy()
    dioptres = np.where(np.isfinite(z) & (z > 0), 1.0 / np.where(z > 0, z, 1.0), np.nan)
    med = running_median(dioptres, median_window)
    known = np.isfinite(med)
    if not known.any():
        raise InputError(f"no known depth at the focus point in any of the {z.size} frames")
    # hold the last known value forward; before the first one, use the first one
    idx = np.where(known, np.arange(z.size), -1)
    np.maximum.accumulate(idx, out=idx)
    idx[idx < 0] = int(np.argmax(known))
    filled = med[idx]
    smooth = one_euro(filled, rate_hz=rate_hz, min_cutoff_hz=min_cutoff_hz, beta=beta, d_cutoff_hz=d_cutoff_hz)
    return 1.0 / smooth


@dataclass(frozen=True, eq=False)
class LensSchedule:
    """The lens of every frame of a sequence.

    Parameters
    ----------
    template : ThinLens or PaperLens, the settings that do not change (focal length, aperture shape, paper weights)
    focus_distance_m : (n,) float64 ndarray, metres
    f_number : (n,) float64 ndarray (ThinLens) or None (PaperLens)
    source : str, how the focus was decided ("fixed", "keyframes", "focus-at X,Y")
    raw_focus_m : (n,) float64 ndarray or None, the unsmoothed focus-point measurements (focus-at only)
    failures : dict or None, {frame index: reason} for frames that cannot be rendered (their lens is a
        placeholder), e.g. every frame when no frame has depth at the followed focus point
    """

    template: object
    focus_distance_m: np.ndarray
    f_number: np.ndarray | None
    source: str
    raw_focus_m: np.ndarray | None = None
    failures: dict | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.template, (ThinLens, PaperLens)):
            raise LensError(f"template must be a ThinLens or PaperLens; got {type(self.template).__name__}")
        focus = np.asarray(self.focus_distance_m, dtype=np.float64)
        if focus.ndim != 1 or not np.all((focus >= MIN_FOCUS_DISTANCE_M) & (focus <= MAX_FOCUS_DISTANCE_M)):
            raise LensError(f"focus_distance_m must be a 1-D array of distances within [{MIN_FOCUS_DISTANCE_M:.3g}, "
                            f"{MAX_FOCUS_DISTANCE_M:.3g}] m")
        object.__setattr__(self, "focus_distance_m", focus)
        if isinstance(self.template, ThinLens):
            fn = np.asarray(self.f_number, dtype=np.float64) if self.f_number is not None else None
            if fn is None or fn.shape != focus.shape or not np.all(np.isfinite(fn) & (fn > 0)):
                raise LensError(f"f_number must be {focus.shape[0]} finite values > 0 for a ThinLens")
            object.__setattr__(self, "f_number", fn)

    def __len__(self) -> int:
        return int(self.focus_distance_m.shape[0])

    def lens_at(self, index: int):
        """The lens of frame *index* (a new ThinLens / PaperLens)."""
        if not 0 <= index < len(self):
            raise InputError(f"frame index must be in [0, {len(self)}); got {index}")
        if isinstance(self.template, ThinLens):
            return replace(self.template, f_number=float(self.f_number[index]),
                           focus_distance_m=float(self.focus_distance_m[index]))
        return replace(self.template, focus_distance_m=float(self.focus_distance_m[index]))

    def describe(self) -> dict:
        """JSON-ready summary (settings that decide the images; used to check --resume)."""
        t = self.template
        lens = {"type": type(t).__name__, **{k: v for k, v in vars(t).items()}}
        return {"source": self.source, "lens": lens}


def build_schedule(template, n_frames: int, *, focus_keyframes=None, f_number_keyframes=None,
                   focus_track_m=None, easing: str = "linear", source: str | None = None,
                   raw_focus_m=None) -> LensSchedule:
    """Decide the lens of every frame.

    Parameters
    ----------
    template : ThinLens or PaperLens, the fixed lens (its focus and f-number apply where nothing else does)
    n_frames : int
    focus_keyframes, f_number_keyframes : sequence of (frame, value) or None
    focus_track_m : (n_frames,) float ndarray or None, per-frame focus (e.g. :func:`smooth_focus_track`)
    easing : a key of :data:`EASINGS`, between keyframes
    source : str or None, description of the focus source for reports
    raw_focus_m : (n_frames,) float ndarray or None, kept in the schedule for reports

    Returns
    -------
    LensSchedule
    """
    if not isinstance(template, (ThinLens, PaperLens)):
        raise LensError(f"lens must be a ThinLens or PaperLens; got {type(template).__name__}")
    if focus_keyframes is not None and focus_track_m is not None:
        raise LensError("focus keyframes and a followed focus point exclude each other; give one")
    if f_number_keyframes is not None and isinstance(template, PaperLens):
        raise LensError("f-number keyframes need the physical method; the paper method has no f-number")
    if focus_track_m is not None:
        focus = np.asarray(focus_track_m, dtype=np.float64)
        if focus.shape != (n_frames,):
            raise InputError(f"focus_track_m must have shape ({n_frames},); got {focus.shape}")
        src = source or "track"
    elif focus_keyframes is not None:
        for frame, value in focus_keyframes:  # each value as the lens would check it, named by its frame
            focus_distance(f"focus keyframe {frame}:{value!r}: the distance", value)
        focus = interpolate_keyframes(focus_keyframes, n_frames, easing=easing)
        src = source or "keyframes"
    else:
        focus = np.full(n_frames, template.focus_distance_m)
        src = source or "fixed"
    f_number = None
    if isinstance(template, ThinLens):
        for frame, value in f_number_keyframes or ():
            positive_number(f"f-number keyframe {frame}:{value!r}: the f-number", value)
        f_number = (interpolate_keyframes(f_number_keyframes, n_frames, easing=easing)
                    if f_number_keyframes is not None else np.full(n_frames, template.f_number))
    raw = None if raw_focus_m is None else np.asarray(raw_focus_m, dtype=np.float64)
    return LensSchedule(template, focus, f_number, src, raw)
