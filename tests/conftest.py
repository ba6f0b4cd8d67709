"""Test-session settings."""

import os

# The pipeline lowers its thread count while other processes keep cores busy (pcdof.plans.threads_for_load).
# Results do not depend on it (tests/test_threads_under_load.py checks that and the adaptation itself), but some
# tests check what a frame does on two threads (the colour side's worker), and a test run shares its machine:
# keep every run on the thread count numba was given.
os.environ.setdefault("PCDOF_ADAPT_THREADS", "0")

# A one-frame CLI command run in this process (click's test runner) would put the kernels compiled ahead of time
# (pcdof.ahead) in place for the rest of the session: tests check numba's kernels unless they choose those
# (tests/test_ahead.py activates them itself and runs the console script in fresh processes).
os.environ.setdefault("PCDOF_AHEAD", "0")


# --------------------------------------------------------------------------- shared fixtures of the hostile-use tests
import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import pytest  # noqa: E402

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
