"""Shared by the side-by-side scripts: an earlier src/pcdof/renderer.py loaded next to the current one."""

import argparse
import importlib.util
import sys


def renderer_arguments(description: str, repeats: int) -> argparse.ArgumentParser:
    """A parser with the arguments every side-by-side script takes: the earlier renderer's file, --repeats
    and --sizes (comma-separated WxH)."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("before", help="an earlier src/pcdof/renderer.py (git show REV:src/pcdof/renderer.py > FILE)")
    ap.add_argument("--repeats", type=int, default=repeats)
    ap.add_argument("--sizes", default="640x480,1920x1080")
    return ap


def sizes(text: str) -> list[tuple[int, int]]:
    """--sizes as (width, height) pairs."""
    return [tuple(int(v) for v in s.split("x")) for s in text.split(",")]


def load_renderer(path: str):
    """The renderer module in *path*, as ``pcdof._renderer_before`` (a fixed name, so numba's cache of its
    kernels is found again on the next run)."""
    spec = importlib.util.spec_from_file_location("pcdof._renderer_before", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module
