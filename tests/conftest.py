"""Test-session settings, and the helpers the test modules share (import them with ``from conftest import ...``).

Marks (pyproject.toml): ``slow`` (left out of the default run), ``subprocess`` (runs pcdof or Python in a child
process) and ``browser`` (drives headless Chromium; skipped where it is absent). The default ``make test`` runs
everything but ``slow``.
"""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

# The pcdof command sets numba's threading-layer order (pcdof.runtime.process.tune_process); a test session
# imports pcdof as a library, which tunes nothing: give numba the same order here, so Open3D's older bundled TBB
# does not make numba warn in every test that loads both.
os.environ.setdefault("NUMBA_THREADING_LAYER_PRIORITY", "omp tbb workqueue")

#: the repository's root (data/, scripts/)
ROOT = Path(__file__).resolve().parents[1]


def invoke(*args, catch_exceptions: bool = True):
    """``pcdof ARGS`` run in this process by click's test runner (arguments given one by one or as one list)."""
    from click.testing import CliRunner

    from pcdof.cli import main

    if len(args) == 1 and isinstance(args[0], (list, tuple)):
        args = tuple(args[0])
    return CliRunner().invoke(main, [str(a) for a in args], prog_name="pcdof", catch_exceptions=catch_exceptions)


def pcdof_command() -> list[str]:
    """The installed ``pcdof`` console script beside this interpreter, or the same entry through ``python -c``."""
    exe = Path(sys.executable).with_name("pcdof")
    if exe.exists():
        return [str(exe)]
    return [sys.executable, "-c", "import pcdof_console; pcdof_console.main()"]


def run_pcdof(args, cwd=None, timeout: float = 300) -> subprocess.CompletedProcess:
    """``pcdof ARGS`` in a child process (text output, no warnings filter, wide terminal)."""
    env = {**os.environ, "PYTHONWARNINGS": "", "COLUMNS": "200"}
    return subprocess.run(pcdof_command() + [os.fsdecode(a) for a in args], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout, env=env, errors="backslashreplace")


def one_line(proc, code: int, *words: str) -> str:
    """Assert that child process *proc* failed with exit status *code* and one ``pcdof: error:`` line on stderr
    (no traceback) naming each of *words* (case-insensitive); returns the line."""
    assert "Traceback" not in proc.stderr, proc.stderr
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("pcdof: error: "), proc.stderr
    assert proc.returncode == code, (proc.returncode, proc.stderr)
    for word in words:
        assert word.lower() in lines[0].lower(), lines[0]
    return lines[0]


def disc_kernel(diameter: float, supersample: int = 16) -> np.ndarray:
    """Anti-aliased uniform disc of the given diameter (pixels), sum 1, by supersampling."""
    r = diameter / 2
    n = int(math.ceil(r + 0.5))
    size = 2 * n + 1
    s = supersample
    offs = (np.arange(size * s) + 0.5) / s - (n + 0.5)
    yy, xx = np.meshgrid(offs, offs, indexing="ij")
    inside = (xx**2 + yy**2 <= r * r).astype(np.float64)
    k = inside.reshape(size, s, size, s).mean(axis=(1, 3))
    return (k / k.sum()).astype(np.float32)


def texture(h: int, w: int, seed: int = 0) -> np.ndarray:
    """(h, w, 3) float32 blocky random texture in [0, 1) (4x4 pixel blocks)."""
    rng = np.random.default_rng(seed)
    noise = rng.random((h // 4 + 1, w // 4 + 1, 3)).astype(np.float32)
    return cv2.resize(noise, (w, h), interpolation=cv2.INTER_NEAREST)[:h, :w]


def highlight_frame(seed, h, w, n_blobs, coc_max):
    """A random linear frame with *n_blobs* clipped discs and boxes (white, or clipped in some channels only,
    some touching the border or each other) and a CoC map of blobs at several blurs, up to *coc_max* px."""
    from pcdof.stages.highlights import CLIP_LEVEL as clip_level

    rng = np.random.default_rng(seed)
    img = (rng.random((h, w, 3)) * 0.7).astype(np.float32)
    coc = np.full((h, w), rng.uniform(0, coc_max), np.float32)
    yy, xx = np.mgrid[:h, :w]
    for _ in range(n_blobs):
        cy, cx, r = rng.integers(0, h), rng.integers(0, w), rng.uniform(0.5, 9)
        inside = (yy - cy) ** 2 + (xx - cx) ** 2 <= r * r if rng.random() < 0.6 else \
            (abs(yy - cy) <= r) & (abs(xx - cx) <= rng.uniform(0.5, 9))
        channels = [c for c in range(3) if rng.random() < 0.7] or [int(rng.integers(3))]
        for c in channels:
            img[..., c][inside] = rng.choice([1.0, clip_level, 0.999])
        coc[inside] = rng.uniform(0, coc_max) * rng.uniform(0.8, 1.2, np.count_nonzero(inside))
    return img, np.where(rng.random((h, w)) < 0.1, -coc, coc)  # (the sign is ignored)


# --------------------------------------------------------------------------- shared fixtures of the hostile-use tests

#: the RealSense D435 sample recording bundled with the repository
SAMPLE_BAG = Path(__file__).resolve().parents[1] / "data" / "real" / "realsense_d435_bag" / \
    "single_depth_color_640x480.bag"
#: size of the small frame fixtures (pixels)
SMALL_W, SMALL_H = 64, 48


@pytest.fixture(scope="session")
def console_script() -> list:
    """The ``pcdof`` console script as a command line: its own entry point (Ctrl-C handled from its first line)."""
    return [sys.executable, "-c", "import pcdof_console; pcdof_console.main()"]


def _write_small_frame(folder: Path, seed: int = 0) -> dict:
    import numpy as np

    from pcdof import io
    from pcdof.camera import Intrinsics, Rig

    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:SMALL_H, 0:SMALL_W]
    io.write_image(folder / "color.png", rng.integers(0, 256, (SMALL_H, SMALL_W, 3), dtype=np.uint8))
    io.write_depth(folder / "depth.png", (1.0 + 0.5 * (xx > SMALL_W // 2) + 0.01 * yy).astype(np.float32))
    rig = Rig.registered(Intrinsics(SMALL_W, SMALL_H, 60.0, 60.0, (SMALL_W - 1) / 2, (SMALL_H - 1) / 2))
    (folder / "calib.json").write_text(json.dumps(rig.to_dict()))
    return {"color": folder / "color.png", "depth": folder / "depth.png", "calib": folder / "calib.json"}


@pytest.fixture()
def small_frame(tmp_path) -> dict:
    """A 64x48 colour PNG, 16-bit depth PNG (two planes, 1 and 1.5 m) and calib.json: {"color", "depth", "calib"}."""
    return _write_small_frame(tmp_path / "frame")


@pytest.fixture()
def small_sequence(tmp_path) -> Path:
    """A folder of six 64x48 frames (color/, depth/, calib.json) that ``pcdof batch`` reads."""
    import shutil

    root = tmp_path / "seq"
    files = _write_small_frame(tmp_path / "one")
    for sub in ("color", "depth"):
        (root / sub).mkdir(parents=True)
        for i in range(6):
            shutil.copy(files[sub], root / sub / f"{i:04d}.png")
    shutil.copy(files["calib"], root / "calib.json")
    return root


@pytest.fixture(scope="session")
def sample_bag() -> Path:
    """The bundled RealSense recording (skipped without rosbags)."""
    pytest.importorskip("rosbags")
    return SAMPLE_BAG


def pytest_collection_modifyitems(config, items):
    """Tests that use the served page in headless Chromium (``served``) carry the ``browser`` mark."""
    for item in items:
        if "served" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.browser)
