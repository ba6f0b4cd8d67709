"""Kernels compiled ahead of time (pcdof.ahead) against numba's: the same frames, the same answers (up to
floating-point reassociation), every kernel a one-frame process calls served by them, other argument types
passed on to numba, never stale code, and the planner's choice of when to use them."""

import dataclasses
import json
import logging
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pcdof import ahead, pipeline
from pcdof.errors import InputError
from pcdof.kernels import cold_stages
from pcdof.plans import AHEAD_MAX_PX, compiled_ahead

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def built():
    """The module for this install (built by ``pcdof warmup``; built here where it is missing)."""
    ahead.deactivate()
    if not ahead.available() and ahead.build() is None:
        pytest.skip("no C compiler here: kernels cannot be compiled ahead of time")
    yield
    ahead.deactivate()


@pytest.fixture
def numba_after():
    yield
    ahead.deactivate()


def _frames():
    from pcdof.io import load_frame
    from pcdof.synth import generate_scene

    sample = ROOT / "data" / "sample"
    frame = load_frame(sample / "color.png", sample / "depth.png", sample / "calib.json")
    yield "sample", frame, None
    yield "sample-16-bit", dataclasses.replace(frame, color=frame.color.astype(np.uint16) * 257), None
    for scene, size, seed in (("portrait", (640, 480), 3), ("highlights", (512, 384), 101), ("fence", (320, 240), 7)):
        sf = generate_scene(scene, color_size=size, depth_size=(512, 424) if size[0] >= 512 else (320, 240), seed=seed)
        yield f"{scene}-{seed}", sf.frame, sf.default_lens


def _lens(frame, lens):
    from pcdof.lens import ThinLens

    if lens is not None:
        return lens
    depth = frame.depth_m[frame.depth_m > 0]
    return ThinLens(focal_length_mm=50.0, f_number=1.8, focus_distance_m=float(np.median(depth)))


def _run(frame, lens, **options):
    return pipeline.run(frame, lens, **options)


@pytest.mark.parametrize("options", [{}, {"highlights": "auto", "quality": "exact"}, {"method": "paper"}],
                         ids=["defaults", "highlights-exact", "paper"])
def test_same_frames_as_numba(built, numba_after, options, caplog):
    for name, frame, lens in _frames():
        lens = _lens(frame, lens)
        ahead.deactivate()
        want = _run(frame, lens, **options)
        assert ahead.activate()
        with caplog.at_level(logging.DEBUG, logger="pcdof.ahead"):
            got = _run(frame, lens, **options)
        # every kernel this frame called was served by the module, none passed on to numba
        assert not [r for r in caplog.records if r.name == "pcdof.ahead"], name
        np.testing.assert_allclose(got.depth_registered_m, want.depth_registered_m, rtol=1e-5, atol=1e-6,
                                   err_msg=name)
        np.testing.assert_allclose(got.depth_filled_m, want.depth_filled_m, rtol=1e-5, atol=1e-6, err_msg=name)
        diff = np.abs(got.image.astype(np.int64) - want.image.astype(np.int64))
        assert diff.max() <= 1, name  # fastmath reassociation moves a value across a rounding edge, at most
        assert np.mean(diff > 0) < 1e-3, name


def test_activate_replaces_every_entry_kernel_and_deactivate_puts_them_back(built, numba_after):
    from numba.core.registry import CPUDispatcher

    before = {(m, name): d for m, name, d in ahead._entry_kernels()}
    assert ahead.activate() and ahead.active()
    assert ahead.activate()  # once is enough; a second call changes nothing
    import importlib

    replaced = {(m, name) for m, name, _ in ahead._replaced}
    assert len(replaced) == len(ahead._replaced)
    for m, name in replaced:
        kernel = getattr(importlib.import_module(m), name)
        assert isinstance(kernel, ahead.AheadKernel) and kernel.dispatcher is before[(m, name)]
        assert kernel.py_func is before[(m, name)].py_func
    for module in ahead.MODULES:
        assert ahead.covers(module), module
    assert cold_stages() == []
    ahead.deactivate()
    assert not ahead.active()
    for (m, name), d in before.items():
        assert getattr(importlib.import_module(m), name) is d
        assert isinstance(d, CPUDispatcher)


def test_other_argument_types_go_to_numba(built, numba_after, caplog):
    from pcdof import lens as lens_module
    from pcdof.kernels import read_only

    z = np.linspace(0.5, 5.0, 101, dtype=np.float32)
    want = np.empty_like(z)
    lens_module._signed_coc(read_only(z), 40.0, 0.5, want)
    assert ahead.activate()
    compiled = lens_module._signed_coc
    calls = []  # numba's dispatcher stands in: a new specialisation would outlive this test
    kernel = ahead.AheadKernel(compiled.variants, type("Numba", (), {"py_func": compiled.py_func,
                                                                       "__call__": lambda self, *a: calls.append(a)})())
    got = np.empty_like(z)
    kernel(read_only(z), 40.0, 0.5, got)  # the compiled types: the module's function
    np.testing.assert_allclose(got, want, rtol=1e-6)
    assert calls == []
    with caplog.at_level(logging.DEBUG, logger="pcdof.ahead"):
        kernel(z, 40.0, 0.5, np.empty_like(z))  # writeable, not the compiled read-only array
        kernel(read_only(z), 40.0, 0.5, np.empty(2 * z.size, np.float32)[::2])  # a non-contiguous output
        # another dtype (one no warm-up compiles: a module built in a process that compiled more holds those too)
        kernel(read_only(z.astype(np.int16)), 40.0, 0.5, np.empty_like(z))
        kernel(read_only(z), 40, 0.5, np.empty_like(z))  # an int where a float was compiled
    assert len(calls) == 4
    assert len(caplog.records) == 4 and "numba's kernel runs it" in caplog.records[0].getMessage()


def _copy_of_package(tmp_path, monkeypatch):
    package = tmp_path / "pcdof"
    shutil.copytree(ROOT / "src" / "pcdof", package, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(ahead, "_PACKAGE", package)
    return package


def test_an_edited_kernel_source_is_never_served_old_code(built, numba_after, tmp_path, monkeypatch):
    before = ahead.fingerprint()
    package = _copy_of_package(tmp_path, monkeypatch)
    assert ahead.fingerprint() == before  # the same sources: the same fingerprint
    source = package / "stages" / "render" / "scatter.py"
    source.write_text(source.read_text() + "\n# edited\n")
    assert ahead.fingerprint() != before
    assert not ahead.available() and not ahead.activate() and not ahead.active()
    edited = ahead.fingerprint()
    # every module defining kernels counts, even one whose kernels are not compiled in (conservative) ...
    source = package / "synth" / "render.py"
    source.write_text(source.read_text() + "\n# edited\n")
    assert ahead.fingerprint() != edited
    # ... and a module defining none does not
    edited = ahead.fingerprint()
    source = package / "plans.py"
    source.write_text(source.read_text() + "\n# edited\n")
    assert ahead.fingerprint() == edited


def test_versions_are_in_the_fingerprint(monkeypatch):
    import numba

    before = ahead.fingerprint()
    monkeypatch.setattr(numba, "__version__", numba.__version__ + ".post1")
    assert ahead.fingerprint() != before


def test_a_damaged_module_is_refused_with_a_warning(built, numba_after, tmp_path, monkeypatch, caplog):
    target, manifest = ahead._paths(ahead.fingerprint())
    monkeypatch.setenv("PCDOF_CACHE_DIR", str(tmp_path))
    copy, note = ahead._paths(ahead.fingerprint())
    assert copy.parent == tmp_path
    copy.write_bytes(b"not a shared object")
    shutil.copy(manifest, note)
    with caplog.at_level(logging.WARNING, logger="pcdof.ahead"):
        assert not ahead.activate()
    assert "pcdof warmup" in caplog.text
    assert not ahead.active()
    # a module without its manifest is not used
    note.unlink()
    shutil.copy(target, copy)
    assert not ahead.available() and not ahead.activate()


def test_cache_dir_follows_the_settings(monkeypatch, tmp_path):
    monkeypatch.setenv("PCDOF_CACHE_DIR", str(tmp_path / "a"))
    assert ahead.cache_dir() == tmp_path / "a"
    monkeypatch.delenv("PCDOF_CACHE_DIR")
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "b"))
    assert ahead.cache_dir() == tmp_path / "b" / "pcdof"


def test_the_planner_chooses_them_for_one_frame_of_moderate_size(monkeypatch):
    monkeypatch.delenv("PCDOF_AHEAD", raising=False)
    assert compiled_ahead(1, 640 * 480)
    assert compiled_ahead(1, AHEAD_MAX_PX)
    assert not compiled_ahead(1, AHEAD_MAX_PX + 1)
    assert not compiled_ahead(2, 640 * 480)
    monkeypatch.setenv("PCDOF_AHEAD", "0")
    assert not compiled_ahead(1, 640 * 480)
    monkeypatch.setenv("PCDOF_AHEAD", "1")
    assert compiled_ahead(50, 10 * AHEAD_MAX_PX)
    for bad in (0, -1, 1.5, True, "1"):
        with pytest.raises(InputError, match="frames must be an integer >= 1"):
            compiled_ahead(bad, 100)
        with pytest.raises(InputError, match="pixels must be an integer >= 1"):
            compiled_ahead(1, bad)


@pytest.mark.parametrize("setting", ["1", "0"])
def test_pcdof_render_says_which_kernels_ran(built, tmp_path, setting):
    sample = ROOT / "data" / "sample"
    out = tmp_path / "out.png"
    done = subprocess.run([sys.executable, "-c", "from pcdof.cli import console_main; console_main()", "render",
                           str(sample / "color.png"), str(sample / "depth.png"), "--calib", str(sample / "calib.json"),
                           "-o", str(out), "--explain"], capture_output=True, text=True, cwd=ROOT,
                          env={**os.environ, "PCDOF_AHEAD": setting})
    assert done.returncode == 0, done.stderr
    assert out.is_file()
    kernels = [line for line in done.stderr.splitlines() if line.startswith("kernels:")]
    assert kernels == (["kernels: compiled ahead of time (one thread)"] if setting == "1" else
                       ["kernels: numba's"])


def test_the_manifest_names_each_signature_once(built):
    _, manifest = ahead._paths(ahead.fingerprint())
    exports = json.loads(manifest.read_text())["exports"]
    signatures = [(e["module"], e["name"], tuple(e["argtypes"])) for e in exports]
    assert len(signatures) == len(set(signatures)) > 20
    assert len({e["export"] for e in exports}) == len(exports)
    assert {m for m, _, _ in signatures} == set(ahead.MODULES)
    # the fill's colour paths: 8-bit (the warm-up's) and float64 (16-bit and float colour: its warmup_ahead)
    combine = [a[1] for m, name, a in signatures if name == "_combine"]
    assert {"readonly array(float64, 3d, C)", "readonly array(uint8, 3d, C)"} <= set(combine)


def test_without_a_compiler_build_says_why_and_leaves_nothing(tmp_path, monkeypatch):
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # pycc's pending-deprecation notice
        from numba.pycc import CC

    def no_compiler(self):
        raise OSError("gcc: command not found")

    monkeypatch.setattr(CC, "compile", no_compiler)
    monkeypatch.setenv("PCDOF_CACHE_DIR", str(tmp_path))
    lines = []
    assert ahead.build(progress=lines.append) is None
    assert any("not built (OSError: gcc: command not found)" in line for line in lines)
    assert list(tmp_path.iterdir()) == []  # the build folder is gone too
    assert not ahead.available() and not ahead.activate()


def test_warmup_command_builds_them_unless_told_not_to(built, tmp_path, monkeypatch):
    from click.testing import CliRunner

    from pcdof.cli import main

    result = CliRunner().invoke(main, ["warmup", "--stages", "fill"])
    assert result.exit_code == 0, result.output
    assert "kernels ahead of time: already built" in result.output
    monkeypatch.setenv("PCDOF_CACHE_DIR", str(tmp_path))
    result = CliRunner().invoke(main, ["warmup", "--stages", "fill", "--no-ahead"])
    assert result.exit_code == 0, result.output
    assert "ahead of time" not in result.output and list(tmp_path.iterdir()) == []


def test_pcdof_register_gives_numba_s_depth_either_way(built, tmp_path):
    sample = ROOT / "data" / "sample"
    out = {}
    for setting in ("1", "0"):
        out[setting] = tmp_path / f"depth{setting}.npy"
        done = subprocess.run([sys.executable, "-c", "from pcdof.cli import console_main; console_main()", "register",
                               str(sample / "color.png"), str(sample / "depth.png"), "--calib",
                               str(sample / "calib.json"), "-o", str(out[setting]), "-q"], capture_output=True,
                              text=True, cwd=ROOT, env={**os.environ, "PCDOF_AHEAD": setting})
        assert done.returncode == 0, done.stderr
    ahead_depth, numba_depth = np.load(out["1"]), np.load(out["0"])
    assert (ahead_depth > 0).mean() > 0.9
    np.testing.assert_allclose(ahead_depth, numba_depth, rtol=1e-5, atol=1e-6)


def test_an_unwritable_cache_folder_is_said_and_nothing_fails(tmp_path, monkeypatch):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("PCDOF_CACHE_DIR", str(blocker / "cache"))
    lines = []
    assert ahead.build(progress=lines.append) is None
    assert any("not built (cannot write" in line for line in lines)
