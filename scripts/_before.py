"""Shared by the side-by-side scripts: an earlier renderer loaded next to the current one."""

import argparse
import importlib.util
import os
import sys


def renderer_arguments(description: str, repeats: int) -> argparse.ArgumentParser:
    """A parser with the arguments every side-by-side script takes: the earlier renderer (a folder or a file, see
    :func:`load_renderer`), --repeats and --sizes (comma-separated WxH)."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("before", help="an earlier src/pcdof/stages/render folder (git archive REV "
                                   "src/pcdof/stages/render | tar -x --strip-components=4 -C DIR), or the "
                                   "src/pcdof/renderer.py of a revision before the render stage became a package "
                                   "(git show REV:src/pcdof/renderer.py > FILE)")
    ap.add_argument("--repeats", type=int, default=repeats)
    ap.add_argument("--sizes", default="640x480,1920x1080")
    return ap


def sizes(text: str) -> list[tuple[int, int]]:
    """--sizes as (width, height) pairs."""
    return [tuple(int(v) for v in s.split("x")) for s in text.split(",")]


def load_renderer(path: str):
    """The renderer in *path*: a folder (an earlier ``src/pcdof/stages/render``) as the package
    ``pcdof.stages._render_before``, or a file (an earlier ``src/pcdof/renderer.py``, which imports the tile map
    as ``pcdof.stages.render.tiles``) as the module ``pcdof._renderer_before``. Fixed names, so numba's cache of its kernels is
    found again on the next run."""
    import pcdof.stages.render.tiles

    if os.path.isdir(path):
        spec = importlib.util.spec_from_file_location("pcdof.stages._render_before", os.path.join(path, "__init__.py"),
                                                      submodule_search_locations=[path])
    else:
        sys.modules.setdefault("pcdof.stages.render.tiles", pcdof.stages.render.tiles)
        spec = importlib.util.spec_from_file_location("pcdof._renderer_before", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module
