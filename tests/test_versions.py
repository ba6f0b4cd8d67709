"""pcdof.versions.library_versions: the library versions a report records, without importing them."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

from pcdof.versions import PACKAGES, library_versions


def test_keys_and_values_match_the_loaded_libraries():
    import cv2

    v = library_versions()
    assert set(PACKAGES) | {"python", "platform", "machine", "cpus", "opencv"} <= set(v)
    assert v["numpy"] == np.__version__
    assert v["opencv"] == cv2.__version__
    assert v["python"] == "{}.{}.{}".format(*sys.version_info[:3])
    assert json.loads(json.dumps(v)) == v


def test_imports_nothing_heavy():
    code = ("import sys; from pcdof.versions import library_versions; v = library_versions(); "
            "assert v['open3d'] is not None; "
            "print(sorted(m for m in ('open3d', 'dask', 'distributed', 'imageio') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
