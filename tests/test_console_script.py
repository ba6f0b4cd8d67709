"""The ``pcdof`` console script (:func:`pcdof.cli.console_main`): exit codes as :func:`pcdof.cli.main`'s, and the
garbage collector told to leave the process's long-lived objects out of its passes."""

import gc
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import pcdof.cli as cli

pytestmark = pytest.mark.subprocess  # most tests here run pcdof in a child process

ROOT = Path(__file__).resolve().parents[1]


def test_the_console_script_installs_the_interrupt_handler_then_runs_console_main():
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["pcdof"] == "pcdof_console:main"
    # the console script's module loads nothing but the standard library: the handler goes in before the
    # pcdof package, click or NumPy load; pcdof.interrupts alone (with the package's light __init__) adds nothing heavy
    code = ("import sys, signal; import pcdof_console; heavy = {'click', 'numpy', 'cv2', 'numba', 'pcdof'}; "
            "assert not heavy & set(sys.modules), heavy & set(sys.modules); "
            "import pcdof.interrupts as i; i.install(); assert i.installed(); "
            "assert signal.getsignal(signal.SIGINT) is not signal.default_int_handler; "
            "assert not {'click', 'numpy', 'cv2', 'numba', 'pcdof.cli'} & set(sys.modules)")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


@pytest.fixture
def unfreeze(monkeypatch):
    """Undo what console_main does to this (test) process."""
    monkeypatch.setattr(cli, "_own_process", False)
    yield
    gc.unfreeze()
    cli._own_process = False


def _console(monkeypatch, *args) -> int:
    monkeypatch.setattr(sys, "argv", ["pcdof", *args])
    with pytest.raises(SystemExit) as done:
        cli.console_main()
    return done.value.code


def test_console_main_freezes_what_the_command_imported(monkeypatch, unfreeze):
    gc.unfreeze()
    assert gc.get_freeze_count() == 0
    assert _console(monkeypatch, "info", "-h") in (0, None)
    assert gc.get_freeze_count() > 0


def test_console_main_keeps_main_s_exit_codes(monkeypatch, unfreeze, capsys):
    assert _console(monkeypatch, "render", "--no-such-flag") == 2
    assert "pcdof: error:" in capsys.readouterr().err
    assert gc.get_freeze_count() > 0  # frozen on the way out of an error too


def test_main_alone_leaves_the_collector_as_it_was(unfreeze):
    from click.testing import CliRunner

    gc.unfreeze()
    result = CliRunner().invoke(cli.main, ["info", "-h"])
    assert result.exit_code == 0
    assert gc.get_freeze_count() == 0


def test_a_fresh_console_process_exits_with_the_error_code(tmp_path):
    missing = tmp_path / "missing.png"
    done = subprocess.run([sys.executable, "-c", "from pcdof.cli import console_main; console_main()", "render",
                           str(missing), str(missing), "--calib", str(ROOT / "data" / "sample" / "calib.json"),
                           "-o", str(tmp_path / "out.png")],
                          capture_output=True, text=True, cwd=ROOT)
    assert done.returncode not in (0, 2)  # pcdof's own input error code, not a usage error
    assert done.stderr.strip().startswith("pcdof: error:")
    assert len(done.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out.png").exists()
